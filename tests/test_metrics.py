"""imaging.metrics' error per pixel and the least error per tile against plain loops."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.metrics import least_error_per_tile, relmse, relmse_per_pixel


def test_the_error_per_pixel_averages_to_relmse():
    rng = np.random.default_rng(1)
    images, reference = rng.random((3, 6, 7, 3)), rng.random((6, 7, 3))
    errors = relmse_per_pixel(images, reference)
    assert errors.shape == (3, 6, 7)
    assert [e.mean() for e in errors] == pytest.approx([relmse(i, reference) for i in images], rel=1e-12)


@pytest.mark.parametrize("shape, tile", [((3, 10, 13), 4), ((2, 8, 8), 8), ((4, 5, 7), 1), ((2, 3, 3), 5)])
def test_the_tiled_choice_takes_the_least_error_of_each_tile(shape, tile):
    errors = np.random.default_rng(sum(shape) + tile).random(shape)
    _, height, width = shape
    total = sum(min(float(e[y:y + tile, x:x + tile].sum()) for e in errors)
                for y in range(0, height, tile) for x in range(0, width, tile))
    assert least_error_per_tile(errors, tile) == pytest.approx(total / (height * width), rel=1e-12)

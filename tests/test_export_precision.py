"""Precision at the largest sample counts: with every sample the same value
(no jitter, direct light from one point light), the export's mean of 2^20
samples equals one sample to < 1e-4, for the noisy pass and the reference."""
from __future__ import annotations

import numpy as np
import pytest
from test_export import rgb

#: one point light over a diffuse floor and sphere: with pixel-centre rays and
#: no bounces, every sample of a pixel carries the same radiance
SCENE = """
PerspectiveCamera { center 0 2 6 direction 0 -0.3 -1 up 0 1 0 angle 40 }
Lights { numLights 1 PointLight { position 1 4 2 color 0.9 0.8 0.7 falloff 0.05 } }
Background { color 0 0 0 ambientLight 0 0 0 }
Materials { numMaterials 2 Material { diffuseColor 0.7 0.7 0.7 } Material { diffuseColor 0.8 0.3 0.2 } }
Group { numObjects 2 MaterialIndex 0 Plane { normal 0 1 0 offset 0 } MaterialIndex 1 Sphere { center 0 1 0 radius 1 } }
"""
#: the bound asked for; a float32 sum of n equal values can be off by (n - 1) 2^-24
TOLERANCE = 1e-4


def export(tmp_path, name: str, spp: int, reference_spp: int, batch_spp: int):
    from export import Spec, export, reference_folder

    scene = tmp_path / "one_light.txt"
    scene.write_text(SCENE)
    spec = Spec.from_dict({"scene": str(scene), "frames": 1, "size": [4, 4], "spp": spp,
                           "reference_spp": reference_spp, "bounces": 0, "jitter": False})
    target = tmp_path / name
    export(spec, target, batch_spp=batch_spp)
    reference = reference_folder(target)
    return {"noisy": rgb(target / "beauty_0.exr"), "half_a": rgb(reference / "half_a_0.exr"),
            "reference": rgb(reference / "beauty_0.exr")}


def relative_error(image, truth) -> float:
    lit = truth > 1e-3
    assert lit.sum() > 8  # most of the 4x4 pixels see the lit floor or sphere
    return float(np.max(np.abs(image[lit].astype(np.float64) - truth[lit]) / truth[lit]))


def check(tmp_path, spp: int, reference_spp: int, batch_spp: int) -> None:
    one = export(tmp_path, "one", spp=1, reference_spp=2, batch_spp=1)
    many = export(tmp_path, "many", spp=spp, reference_spp=reference_spp, batch_spp=batch_spp)
    for name in one:
        error = relative_error(many[name], one[name])
        assert error < TOLERANCE, (name, error)


def test_two_to_the_twenty_samples_equal_one(tmp_path, variant_rgb):
    """The noisy pass at 2^20 spp (1024 renders), the reference at 2^14 in
    batches of 2^13 (each split in 8): both over the per-render limit."""
    check(tmp_path, spp=2 ** 20, reference_spp=2 ** 14, batch_spp=2 ** 13)


@pytest.mark.slow
def test_two_to_the_twenty_reference_samples_equal_one(tmp_path, variant_rgb):
    check(tmp_path, spp=1, reference_spp=2 ** 20, batch_spp=2 ** 19)

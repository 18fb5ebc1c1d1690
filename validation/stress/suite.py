"""Every stress case of every surface, in one list (:class:`validation.stress.StressCase`)."""
from __future__ import annotations

from validation.stress import StressCase
from validation.stress.cases_denoiser import denoise_cases
from validation.stress.cases_inputs import all_input_cases
from validation.stress.cases_renderer import error_cases, render_cases
from validation.stress.cases_scale import scale_cases
from validation.stress.cases_surfaces import surface_cases
from validation.stress.cases_system import system_cases


def all_cases() -> list[StressCase]:
    """The renderer's, the inputs', the system's, the newer surfaces' and the denoiser's cases."""
    return [*render_cases(), *error_cases(), *scale_cases(), *all_input_cases(), *system_cases(), *surface_cases(),
            *denoise_cases()]

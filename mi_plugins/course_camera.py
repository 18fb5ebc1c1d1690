from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .camera_basis import course_camera_basis


class CourseCamera(mi.Sensor):
    r"""
    .. _sensor-course_camera:

    Course perspective camera (:monosp:`course_camera`)
    ----------------------------------------------------

    .. pluginparameters::

     * - origin
       - |point|
       - Centre of projection (Default: 0, 0, 0)
       - |exposed|

     * - direction
       - |vector|
       - Viewing direction; normalised (Default: 0, 0, -1)
       - |exposed|

     * - up
       - |vector|
       - Up vector, used exactly as given: it is neither normalised nor made
         orthogonal to ``direction``, as in the course's solution (Default: 0, 1, 0)
       - |exposed|

     * - fov
       - |float|
       - Full field of view in degrees, applied to *both* image axes, so a
         non-square image is stretched, as in the course (Default: 30)
       - |exposed|

     * - pixel_centers
       - |bool|
       - Shoot every sample through the pixel's centre, ignoring the
         sampler's sub-pixel offset (the course's plain ray casting). Set it
         to false for jittered supersampling (Default: true)

    The course's ray generation. Pixel :math:`(i, j)` of a :math:`W \times H`
    image (row 0 at the top) has normalised coordinates
    :math:`x = 2i/(W-1) - 1` and :math:`y = 1 - 2j/(H-1)`, so the outermost
    pixel centres lie exactly on :math:`\pm 1`. The ray through
    :math:`(x, y)` has direction
    :math:`\mathrm{normalize}(D / \tan(\mathrm{fov}/2) + x\,H + y\,U)` with
    :math:`D` the unit direction, :math:`H = \mathrm{normalize}(D \times U)`
    and :math:`U` the up vector as given. Sub-pixel positions (when
    ``pixel_centers`` is false) extend the same affine map continuously.
    The basis is :func:`mi_plugins.camera_basis.course_camera_basis` (the
    one the denoiser's frame matrices use). ``traverse`` exposes ``origin``,
    ``direction``, ``up`` and ``fov`` as non-differentiable parameters (the
    basis is computed on the host); ``parameters_changed`` recomputes it.

    .. tabs::

        .. code-tab:: python

            'type': 'course_camera',
            'origin': [0, 0, 10], 'direction': [0, 0, -1], 'up': [0, 1, 0],
            'fov': 30,
            'film': {'type': 'hdrfilm', 'width': 800, 'height': 800}
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.origin = mi.Point3f(props.get("origin", mi.ScalarPoint3f(0, 0, 0)))
        self.direction = mi.Vector3f(props.get("direction", mi.ScalarVector3f(0, 0, -1)))
        self.up = mi.Vector3f(props.get("up", mi.ScalarVector3f(0, 1, 0)))
        self.fov = mi.Float(props.get("fov", 30.0))
        self.pixel_centers = bool(props.get("pixel_centers", True))
        self.parameters_changed()

    def parameters_changed(self, keys: list[str] | None = None):
        """Recomputes the ray basis from ``origin``, ``direction``, ``up`` and
        ``fov``, and the pixel mapping from the film."""
        def host(value) -> np.ndarray:
            return np.asarray(value, np.float64).reshape(-1)

        basis = course_camera_basis(host(self.direction)[:3], host(self.up)[:3], float(dr.slice(self.fov, 0)))
        self.ray_origin = mi.ScalarPoint3f(host(self.origin)[:3])
        self.forward = mi.ScalarVector3f(basis.forward)
        self.horizontal = mi.ScalarVector3f(basis.horizontal)
        self.vertical = mi.ScalarVector3f(basis.up)
        film = self.film()
        size = film.size()
        # position samples span the film's crop window (a band of the image
        # when it is rendered in parts); NDC always refer to the whole image
        self.crop_offset = mi.ScalarVector2f(film.crop_offset())
        self.crop_size = mi.ScalarVector2f(film.crop_size())
        # NDC = (pixel centre - 0.5) * scale + bias; a 1-pixel axis maps to 0
        self.ndc_scale = mi.ScalarVector2f([2.0 / (s - 1) if s > 1 else 0.0 for s in size])
        self.ndc_bias = mi.ScalarVector2f([-1.0 if s > 1 else 0.0 for s in size])

    def _direction(self, position_sample: mi.Point2f) -> mi.Vector3f:
        # continuous pixel coordinates, origin at the image's top-left corner
        pixel = self.crop_offset + position_sample * self.crop_size
        if self.pixel_centers:
            pixel = dr.floor(pixel) + 0.5
        ndc_x = (pixel.x - 0.5) * self.ndc_scale.x + self.ndc_bias.x
        ndc_y = -((pixel.y - 0.5) * self.ndc_scale.y + self.ndc_bias.y)
        return dr.normalize(self.forward + ndc_x * self.horizontal + ndc_y * self.vertical)

    def sample_ray(self, time: mi.Float, sample1: mi.Float, sample2: mi.Point2f, sample3: mi.Point2f,
                   active: bool = True) -> tuple[mi.Ray3f, mi.Color3f]:
        wavelengths, weight = self.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f), sample1, active)
        ray = mi.Ray3f(mi.Point3f(self.ray_origin), self._direction(sample2), time, wavelengths)
        return ray, weight

    def sample_ray_differential(self, time: mi.Float, sample1: mi.Float, sample2: mi.Point2f,
                                sample3: mi.Point2f, active: bool = True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        ray = mi.RayDifferential3f(ray)
        ray.has_differentials = False
        return ray, weight

    def bbox(self) -> mi.ScalarBoundingBox3f:
        # (scalar variants name the scalar type without the "Scalar" prefix)
        box = getattr(mi, "ScalarBoundingBox3f", None) or mi.BoundingBox3f
        return box(self.ray_origin)

    def traverse(self, callback):
        super().traverse(callback)  # the film
        # the basis is computed on the host (camera_basis.py), so these are
        # not differentiable: a change recompiles the ray generation
        for name in ("origin", "direction", "up", "fov"):
            callback.put(name, getattr(self, name), mi.ParamFlags.NonDifferentiable)

    def to_string(self):
        return (f"CourseCamera[\n  origin = {self.ray_origin},\n  forward = {self.forward},\n"
                f"  up = {self.vertical},\n  pixel_centers = {self.pixel_centers}\n]")

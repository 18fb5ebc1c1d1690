"""What the whitted integrator knows of a scene before it traces: its lights
(unrolled, or a table for a symbolic loop), whether it has mirrors, and per
shape an object id, a ray offset and a size. Independent of the variant's
plugin bases, so it is an ordinary module (the integrator's module is run once
per variant, see :mod:`mi_plugins`)."""
from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np

from .aovs import OBJECT_ID_PREFIX

#: Light kinds of the light table (the symbolic light loop)
POINT, DIRECTIONAL = 0, 1

_OBJECT_ID = re.compile(OBJECT_ID_PREFIX + r"(\d+)(?:_part\d+)?")


def object_index(shape: mi.Shape, position: int) -> int:
    """Object id of a shape: ``k`` from its id ``object_<k>`` or ``object_<k>_part<j>``
    (the converter's names), else its position in the scene."""
    match = _OBJECT_ID.fullmatch(shape.id())
    return int(match.group(1)) if match else position


class LightTable:
    """Point and directional lights as Dr.Jit arrays, for the symbolic light loop.

    (Plain classes, not dataclasses: Dr.Jit would take a dataclass's arrays
    for loop state.)"""

    def __init__(self, kinds: list[int], vectors: list[float], values: list[float]):
        self.count = len(kinds)
        self.count_opaque = dr.opaque(mi.UInt32, self.count)
        # flat tensors: indexing ".array[i]" gathers in vectorised variants and reads in scalar ones
        self.kinds = mi.TensorXu(np.array(kinds, np.uint32))  # POINT or DIRECTIONAL
        self.vectors = mi.TensorXf(np.array(vectors, np.float32))  # 3 per light: position, or unit direction towards it
        self.values = mi.TensorXf(np.array(values, np.float32))  # 3 per light: intensity (point) or irradiance

    @staticmethod
    def of(lights: list) -> LightTable:
        """The table of ``(emitter, kind)`` pairs, kinds from :func:`light_kind`."""
        # (values read one by one: evaluating them together makes one kernel with
        # thousands of outputs, which LLVM compiles for a minute)
        kinds, vectors, values = [], [], []
        for light, kind in lights:
            params = mi.traverse(light)
            kinds.append(kind)
            if kind == POINT:
                vectors += first_three(params["position"])
                values += first_three(params["intensity.value"])
            else:
                # the directional emitter's travel direction is its to_world's +z
                vectors += [-v for v in first_three(params["to_world"] @ mi.Vector3f(0.0, 0.0, 1.0))]
                values += first_three(params["irradiance.value"])
        return LightTable(kinds, vectors, values)

    def vector(self, table: mi.TensorXf, index: mi.UInt32):
        return mi.Vector3f(table.array[3 * index], table.array[3 * index + 1], table.array[3 * index + 2])


class SceneAnalysis:
    """What the kernel needs to know about one scene, kept while the scene holds
    the same shapes and emitters (never looked up by ``id(scene)``) and, at
    each render, has the same :func:`scene_state`. The light table's values
    are read once: a point or directional light changed through
    ``mi.traverse`` is seen at once when it is unrolled (up to
    ``max_unrolled_lights``), after :meth:`WhittedIntegrator.forget` in the
    symbolic light loop."""

    def __init__(self, shapes, emitters, unrolled, table, mirrors, slots, tables):
        self.shapes = shapes  # held, so that their identity shows the analysis belongs to a scene
        self.emitters = emitters
        self.unrolled = unrolled  # delta lights shaded one by one (Python loop at trace time)
        self.table: LightTable | None = table  # point and directional lights shaded in a symbolic loop
        self.mirrors = mirrors  # any mirror lobe
        self.slots = slots  # shape id -> row of the per-shape tables (scalar variants; 0: no shape)
        self.tables = tables  # "ids", "epsilons", "scales" -> mi.TensorXf, one row per shape slot
        self.bsphere = (0.0, 0.0, 0.0, 0.0)  # scene's bounding sphere (centre, radius), for directional lights
        self.state: tuple = ()  # scene_state() when analysed

    def belongs_to(self, scene: mi.Scene) -> bool:
        shapes, emitters = scene.shapes(), scene.emitters()
        return (len(shapes) == len(self.shapes) and len(emitters) == len(self.emitters)
                and all(a is b for a, b in zip(shapes, self.shapes))
                and all(a is b for a, b in zip(emitters, self.emitters)))

    def shape_slot(self, si: mi.SurfaceInteraction3f) -> mi.UInt32:
        """Row of the hit shape in :attr:`tables` (0: none). The one place where
        variants differ: a vectorised shape pointer is its registry index, a
        scalar one is the shape itself."""
        if dr.is_jit_v(mi.Float):
            return dr.reinterpret_array(mi.UInt32, si.shape)
        return 0 if si.shape is None else self.slots[si.shape.id()]

    def per_shape(self, si: mi.SurfaceInteraction3f, name: str) -> mi.Float:
        """The hit shape's entry of table ``ids``, ``epsilons`` or ``scales``."""
        return self.tables[name].array[self.shape_slot(si)]


def scene_state(scene: mi.Scene) -> tuple:
    """What parameter updates may change of an analysis, cheap to read once per
    render: each shape's BSDF flags (mirror lobes) and the scene's bounding box
    (the shapes' scales, the directional lights' reach)."""
    box = scene.bbox()
    return (tuple(int(s.bsdf().flags()) if s.bsdf() is not None else -1 for s in scene.shapes()),
            tuple(first_three(box.min)), tuple(first_three(box.max)))


def light_kind(light: mi.Emitter) -> int | None:
    """POINT or DIRECTIONAL for Mitsuba's ``point`` and ``directional`` emitters with
    constant colours, else None (shaded through the emitter's own methods)."""
    name = str(light).split("[", 1)[0]
    params = mi.traverse(light)
    if name == "PointLight" and "intensity.value" in params:
        return POINT
    if name == "DirectionalEmitter" and "irradiance.value" in params:
        return DIRECTIONAL
    return None


def first_three(value) -> list[float]:
    """The first three components of a Mitsuba or NumPy vector, as Python floats."""
    return [float(v) for v in np.asarray(value, np.float64).reshape(-1)[:3]]


def analyse_scene(scene: mi.Scene, max_unrolled_lights: int, ray_epsilon: float,
                  ray_epsilons: list[float]) -> SceneAnalysis:
    """What the whitted kernel needs to know of ``scene``: the delta lights it
    unrolls, or above ``max_unrolled_lights`` point and directional lights the
    light table of a symbolic loop; whether any shape has a mirror lobe; per
    shape its object id, its ray offset (``ray_epsilons`` by object id, else
    ``ray_epsilon``) and its size (for offsets relative to it)."""
    shapes, emitters = scene.shapes(), scene.emitters()
    lights = [e for e in emitters if mi.has_flag(e.flags(), mi.EmitterFlags.Delta)]
    kinds = [light_kind(light) for light in lights]
    looped = sum(k is not None for k in kinds) > max_unrolled_lights
    unrolled = [light for light, kind in zip(lights, kinds) if not (looped and kind is not None)]
    table = LightTable.of([(light, k) for light, k in zip(lights, kinds) if k is not None]) if looped else None
    mirrors = any(s.bsdf() is not None and mi.has_flag(s.bsdf().flags(), mi.BSDFFlags.DeltaReflection)
                  for s in shapes)
    # table rows: a vectorised shape pointer is a registry index (0: none), a scalar
    # one is numbered here
    if dr.is_jit_v(mi.Float):
        rows = [int(v) for v in np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr())).reshape(-1)]
    else:
        rows = list(range(1, len(shapes) + 1))
    columns = {"ids": np.full(max(rows, default=0) + 1, -1.0, np.float32)}
    columns["epsilons"] = np.full_like(columns["ids"], ray_epsilon)
    columns["scales"] = np.zeros_like(columns["ids"])
    for position, (shape, row) in enumerate(zip(shapes, rows)):
        k = object_index(shape, position)
        columns["ids"][row] = k
        columns["epsilons"][row] = ray_epsilons[k] if k < len(ray_epsilons) else ray_epsilon
        box = shape.bbox()
        columns["scales"][row] = float(max(dr.max(dr.abs(box.min)), dr.max(dr.abs(box.max))))
    tables = {name: mi.TensorXf(values) for name, values in columns.items()}
    slots = {shape.id(): row for shape, row in zip(shapes, rows)}
    analysis = SceneAnalysis(shapes, emitters, unrolled, table, mirrors, slots, tables)
    analysis.state = scene_state(scene)
    if shapes:
        sphere = scene.bbox().bounding_sphere()
        analysis.bsphere = (*first_three(sphere.center), float(sphere.radius))
    return analysis

"""Procedurally generated training scenes and sequences for the denoiser's network.

    write_sequences(folder, count)   # folder/procedural_000.txt, .json, ... (scene and sequence spec)

``learned-asvgf`` trained on the project's four training scenes improved
those scenes and left scenes it had not seen where asvgf is; with these
scenes added it carries over (docs/learned_asvgf.md). Each scene is drawn
from ``numpy.random.default_rng((seed, index))``, so a fresh machine writes
the same text: a floor plane (and, in some, a back wall), 3 to 7 objects
(spheres, ellipsoids, the torus and the gem of ``scenes/meshes``) of six
materials (light and dark, matte, glossy of shininess 3 to 600, mirror-like),
1 to 3 lights (the first a point light; others point or directional), a
dark background or the sky cube map. Each sequence is 7 frames at 320×180,
1 spp, 128-spp ground truth, with one motion: the camera orbits, dollies or
pans, and an object moves, a point light moves or a light switches.
Scenes refer to the meshes and the sky by absolute path (they are written
into a work folder, not beside them).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ASSETS = Path(__file__).resolve().parent
#: the set's seed: another seed is another set of scenes
SEED = 1
#: what every sequence's spec holds besides its scene, seed and motion
SEQUENCE = {"frames": 7, "size": [320, 180], "spp": 1, "reference_spp": 128, "bounces": 3}
MATERIALS = 6


def numbers(values) -> str:
    return " ".join(f"{x:.3f}" for x in values)


def camera(rng: np.random.Generator) -> str:
    distance, height, azimuth = rng.uniform(8, 11), rng.uniform(2, 4.5), rng.uniform(-0.5, 0.5)
    eye = np.array([distance * np.sin(azimuth), height, distance * np.cos(azimuth)])
    direction = np.array([0, rng.uniform(0.3, 1.2), 0]) - eye
    direction /= np.linalg.norm(direction)
    return (f"PerspectiveCamera {{ center {numbers(eye)} direction {numbers(direction)} up 0 1 0 "
            f"angle {rng.uniform(38, 52):.1f} }}")


def lights(rng: np.random.Generator) -> list[str]:
    """1 to 3 lights, the first a point light (a sequence may move it)."""
    result = []
    for k in range(rng.integers(1, 4)):
        if k > 0 and rng.random() < 0.4:
            direction = [rng.uniform(-0.7, 0.7), -1, rng.uniform(-0.7, 0.3)]
            result.append(f"DirectionalLight {{ direction {numbers(direction)} "
                          f"color {numbers(rng.uniform(0.3, 0.8, 3))} }}")
        else:
            position = [rng.uniform(-5, 5), rng.uniform(1.5, 6), rng.uniform(-2, 5)]
            colour = rng.uniform(0.4, 1.0, 3)
            falloff = np.exp(rng.uniform(np.log(0.02), np.log(0.5)))
            result.append(f"PointLight {{ position {numbers(position)} color {numbers(colour)} "
                          f"falloff {falloff:.3f} }}")
    return result


def background(rng: np.random.Generator) -> str:
    sky = rng.random() < 0.3
    colour, ambient = rng.uniform(0, 0.3, 3), np.full(3, rng.uniform(0.02, 0.1))
    return (f"Background {{ color {numbers(colour)} ambientLight {numbers(ambient)}"
            + (f" cubeMap {ASSETS / 'tex' / 'sky'}" if sky else "") + " }")


def material(rng: np.random.Generator) -> str:
    diffuse = rng.uniform(0.5, 0.9, 3) if rng.random() < 0.6 else rng.uniform(0.02, 0.5, 3)
    kind = rng.random()
    if kind < 0.45:
        return f"Material {{ diffuseColor {numbers(diffuse)} }}"
    if kind < 0.85:
        specular = np.full(3, rng.uniform(0.1, 0.9))
        shininess = np.exp(rng.uniform(np.log(3), np.log(600)))
        return (f"Material {{ diffuseColor {numbers(diffuse)} specularColor {numbers(specular)} "
                f"shininess {shininess:.0f} }}")
    return (f"Material {{ diffuseColor {numbers(diffuse * 0.2)} "
            f"specularColor {numbers(np.full(3, rng.uniform(0.6, 0.95)))} shininess 1000 }}")


def objects(rng: np.random.Generator) -> list[str]:
    """The floor, maybe a back wall (two triangles), then 3 to 7 objects, each after its MaterialIndex."""
    lines = [f"MaterialIndex {rng.integers(0, MATERIALS)}", "Plane { normal 0 1 0 offset 0 }"]
    if rng.random() < 0.6:
        z = rng.uniform(-5, -3)
        lines += [f"MaterialIndex {rng.integers(0, MATERIALS)}",
                  f"Triangle {{ vertex0 -10 0 {z:.2f}  vertex1 10 0 {z:.2f}  vertex2 10 8 {z:.2f} }}",
                  f"Triangle {{ vertex0 -10 0 {z:.2f}  vertex1 10 8 {z:.2f}  vertex2 -10 8 {z:.2f} }}"]
    for _ in range(rng.integers(3, 8)):
        x, z = rng.uniform(-4, 4), rng.uniform(-2.5, 2.5)
        lines.append(f"MaterialIndex {rng.integers(0, MATERIALS)}")
        kind, size = rng.random(), rng.uniform(0.4, 1.2)
        if kind < 0.4:
            lines.append(f"Sphere {{ center {x:.2f} {size:.2f} {z:.2f} radius {size:.2f} }}")
        elif kind < 0.65:
            scale = rng.uniform(0.3, 1.5, 3) * size
            lines.append(f"Transform {{ Translate {x:.2f} {scale[1] + rng.uniform(0, 1):.2f} {z:.2f}  "
                         f"YRotate {rng.uniform(0, 180):.0f}  Scale {numbers(scale)}  "
                         f"Sphere {{ center 0 0 0 radius 1 }} }}")
        else:
            mesh = ASSETS / "meshes" / ("torus.obj" if kind < 0.85 else "gem.obj")
            lines.append(f"Transform {{ Translate {x:.2f} {size + rng.uniform(0, 0.8):.2f} {z:.2f}  "
                         f"Rotate {{ {numbers(rng.normal(size=3))} {rng.uniform(0, 180):.0f} }}  "
                         f"UniformScale {size * 1.2:.2f}  TriangleMesh {{ obj_file {mesh} }} }}")
    return lines


def block(name: str, count_key: str, number: int, items: list[str]) -> str:
    """``name { count_key number  item ... }``, one item a line."""
    inside = "\n    ".join(items)
    return f"{name} {{\n    {count_key} {number}\n    {inside}\n}}"


def scene(rng: np.random.Generator) -> tuple[str, int, int]:
    """(the scene's text, its object count, its light count)."""
    view = camera(rng)
    lit = lights(rng)
    parts = [view, block("Lights", "numLights", len(lit), lit), background(rng),
             block("Materials", "numMaterials", MATERIALS, [material(rng) for _ in range(MATERIALS)])]
    group = objects(rng)
    count = sum(not line.startswith("MaterialIndex") for line in group)
    parts.append(block("Group", "numObjects", count, group))
    text = "# a procedural training scene (scenes/procedural.py)\n# render: -bounces 3 -shadows\n\n"
    return text + "\n\n".join(parts) + "\n", count, len(lit)


def motion(rng: np.random.Generator, object_count: int, light_count: int) -> dict:
    """The spec's camera, object and light keys: a camera move and one change in the scene, or either."""
    change = rng.integers(0, 6)
    cameras = [{"orbit": {"center": [0, 0, 0], "degrees": float(rng.choice([-1, 1]) * rng.uniform(10, 30))}},
               {"dolly": float(rng.uniform(0.5, 2.0))}, {"pan": [float(rng.uniform(-0.8, 0.8)), 0, 0]}, {}]
    result = {"camera": cameras[rng.integers(0, 4)]}
    if change in (0, 1):  # an object other than the floor moves
        moved = int(rng.integers(1, object_count))
        result["objects"] = {str(moved): {"translate": [float(rng.uniform(-2, 2)), 0, float(rng.uniform(-1, 1))]}}
    elif change == 2:  # the first light (a point light) moves
        result["lights"] = {"0": {"translate": [float(rng.uniform(-4, 4)), 0, float(rng.uniform(-2, 2))]}}
    elif change == 3:  # a light is switched down for frames 3 and 4
        result["lights"] = {str(int(rng.integers(0, light_count))): {"scale": float(rng.uniform(0.1, 0.2)),
                                                                      "frames": [3, 4]}}
    if not result["camera"] and len(result) == 1:  # nothing would move
        result["camera"] = {"pan": [0.5, 0, 0]}
    if not result["camera"]:
        del result["camera"]
    return result


def write_sequences(folder: Path, count: int, seed: int = SEED) -> list[Path]:
    """Writes ``count`` scenes and their sequence specs into ``folder``
    (``procedural_NNN.txt`` and ``.json``; files already there with the same text
    are left as they are); returns the specs' paths."""
    folder.mkdir(parents=True, exist_ok=True)
    specs = []
    for index in range(count):
        rng = np.random.default_rng((seed, index))
        text, object_count, light_count = scene(rng)
        name = f"procedural_{index:03d}"
        spec = {"scene": str(folder.resolve() / f"{name}.txt"), **SEQUENCE, "seed": 1000 * seed + index,
                **motion(rng, object_count, light_count)}
        for path, content in ((folder / f"{name}.txt", text), (folder / f"{name}.json", json.dumps(spec) + "\n")):
            if not path.is_file() or path.read_text() != content:
                path.write_text(content)
        specs.append(folder / f"{name}.json")
    return specs

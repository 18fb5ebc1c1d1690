"""A plain NumPy ray tracer with the course's semantics, as the tests' reference.

Independent of Mitsuba and of our plugins: it follows the course's README
(camera, Phong, falloff, shadows, mirror recursion, cube map, normal and depth
images) the way the course's C++ solution does it, in float64, brute force
over all primitives. Shared with the code under test: the scene parser
(tested on its own), the secondary-ray epsilon and the camera basis (one
place, ``mi_plugins/camera_basis.py``; the course's own images check it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from converters.description import ray_epsilons
from converters.model import DirectionalLight, Plane, Scene, Sphere, Triangle, TriangleMesh
from imaging.image_io import read_cube_map
from mi_plugins.camera_basis import course_camera_basis


def normalize(v: np.ndarray) -> np.ndarray:
    v = np.nan_to_num(np.asarray(v, np.float64))  # misses carry NaN/inf; they become 0
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


@dataclass
class Hits:
    t: np.ndarray        # (R,) inf on a miss
    normal: np.ndarray   # (R, 3) world shading normal
    material: np.ndarray  # (R,) int, -1 on a miss
    index: np.ndarray  # (R,) object index, -1 on a miss


class ReferenceTracer:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.epsilons = np.asarray(ray_epsilons(scene) + [0.0])  # per object (index -1: none)
        self.cube = None
        if scene.background.cube_map is not None:
            self.cube = read_cube_map(scene.background.cube_map)[..., :3].astype(np.float64)

    # -- camera ---------------------------------------------------------------
    def camera_rays(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        cam = self.scene.camera
        basis = course_camera_basis(cam.direction, cam.up, cam.angle)
        xs = 2 * np.arange(width) / (width - 1) - 1 if width > 1 else np.zeros(1)
        ys = 1 - 2 * np.arange(height) / (height - 1) if height > 1 else np.zeros(1)
        x, y = np.meshgrid(xs, ys)
        dirs = normalize(basis.forward + x[..., None] * basis.horizontal + y[..., None] * basis.up)
        origins = np.broadcast_to(np.asarray(cam.center, np.float64), dirs.shape)
        return origins.reshape(-1, 3), dirs.reshape(-1, 3)

    # -- intersection -----------------------------------------------------------
    def intersect(self, o: np.ndarray, d: np.ndarray, tmin: float) -> Hits:
        n_rays = len(o)
        best = Hits(np.full(n_rays, np.inf), np.zeros((n_rays, 3)), np.full(n_rays, -1), np.full(n_rays, -1))
        tmin = np.broadcast_to(np.asarray(tmin, np.float64), (n_rays,))  # per ray: the epsilon of its origin
        for index, obj in enumerate(self.scene.objects):
            t, normal = self._intersect_object(obj, o, d, tmin)
            closer = t < best.t
            best.t[closer] = t[closer]
            best.normal[closer] = normal[closer]
            best.material[closer] = obj.material
            best.index[closer] = index
        return best

    def _intersect_object(self, obj, o, d, tmin):
        m = obj.to_world
        inv = np.linalg.inv(m)
        if isinstance(obj, Sphere):
            # the course's way: the ray goes to object space, the normal comes back
            oo = o @ inv[:3, :3].T + inv[:3, 3] - np.asarray(obj.center)
            dd = d @ inv[:3, :3].T
            a = np.sum(dd * dd, -1)
            b = 2 * np.sum(oo * dd, -1)
            c = np.sum(oo * oo, -1) - obj.radius ** 2
            disc = b * b - 4 * a * c
            root = np.sqrt(np.maximum(disc, 0))
            t0, t1 = (-b - root) / (2 * a), (-b + root) / (2 * a)
            t = np.where(t0 > tmin, t0, np.where(t1 > tmin, t1, np.inf))
            t = np.where(disc >= 0, t, np.inf)
            with np.errstate(invalid="ignore"):
                local = oo + t[:, None] * dd
            normal = normalize(np.nan_to_num(local / obj.radius) @ inv[:3, :3])
            return t, normal
        if isinstance(obj, Plane):
            n = normalize(np.asarray(obj.normal, np.float64))
            point = m[:3, :3] @ (n * obj.offset) + m[:3, 3]
            wn = normalize(inv[:3, :3].T @ n)
            denom = d @ wn
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((point - o) @ wn) / denom
            t = np.where((np.abs(denom) > 0) & (t > tmin), t, np.inf)
            return t, np.broadcast_to(wn, o.shape)
        if isinstance(obj, Triangle):
            v = np.asarray(obj.vertices, np.float64) @ m[:3, :3].T + m[:3, 3]
            t, _, _, _ = self._triangles(o, d, tmin, v[None, 0], v[None, 1], v[None, 2])
            n = normalize(np.cross(v[1] - v[0], v[2] - v[0]))
            return t, np.broadcast_to(n, o.shape)
        if isinstance(obj, TriangleMesh):
            p = obj.positions @ m[:3, :3].T + m[:3, 3]
            f = obj.faces.astype(np.int64)
            # only rays that pass the mesh's bounding sphere are tested (speed)
            centre = (p.min(0) + p.max(0)) / 2
            radius = np.linalg.norm(p - centre, axis=1).max() * 1.001
            oc = centre - o
            closest = np.sum(oc * d, -1)
            near = np.sum(oc * oc, -1) - np.maximum(closest, 0) ** 2 <= radius ** 2
            t, index = np.full(len(o), np.inf), np.zeros(len(o), np.int64)
            b1, b2 = np.zeros(len(o)), np.zeros(len(o))
            if near.any():
                t[near], index[near], b1[near], b2[near] = self._triangles(
                    o[near], d[near], tmin[near], p[f[:, 0]], p[f[:, 1]], p[f[:, 2]])
            # vertex normals: mean of unit face normals in object space, then M^-T
            q = obj.positions
            fn = normalize(np.cross(q[f[:, 1]] - q[f[:, 0]], q[f[:, 2]] - q[f[:, 0]]))
            vn = np.zeros_like(q)
            for k in range(3):
                np.add.at(vn, f[:, k], fn)
            vn = normalize(vn)
            hit = np.isfinite(t)
            tri = f[np.where(hit, index, 0)]
            b0 = 1 - b1 - b2
            n_obj = b0[:, None] * vn[tri[:, 0]] + b1[:, None] * vn[tri[:, 1]] + b2[:, None] * vn[tri[:, 2]]
            return t, normalize(n_obj @ inv[:3, :3])
        raise TypeError(type(obj))

    @staticmethod
    def _triangles(o, d, tmin, v0, v1, v2, chunk: int = 256):
        """Moller-Trumbore, rays x triangles; returns (t, triangle, b1, b2) of the nearest."""
        n_rays = len(o)
        best_t = np.full(n_rays, np.inf)
        best_i = np.zeros(n_rays, np.int64)
        best_b1, best_b2 = np.zeros(n_rays), np.zeros(n_rays)
        for start in range(0, len(v0), chunk):
            a, e1, e2 = v0[start:start + chunk], v1[start:start + chunk] - v0[start:start + chunk], \
                v2[start:start + chunk] - v0[start:start + chunk]
            pvec = np.cross(d[:, None, :], e2[None])
            det = np.sum(e1[None] * pvec, -1)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv_det = 1.0 / det
                tvec = o[:, None, :] - a[None]
                u = np.sum(tvec * pvec, -1) * inv_det
                qvec = np.cross(tvec, e1[None])
                v = np.sum(d[:, None, :] * qvec, -1) * inv_det
                t = np.sum(e2[None] * qvec, -1) * inv_det
            ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tmin[:, None])
            t = np.where(ok, t, np.inf)
            i = np.argmin(t, axis=1)
            tt = t[np.arange(n_rays), i]
            closer = tt < best_t
            best_t[closer] = tt[closer]
            best_i[closer] = start + i[closer]
            best_b1[closer] = u[np.arange(n_rays), i][closer]
            best_b2[closer] = v[np.arange(n_rays), i][closer]
        return best_t, best_i, best_b1, best_b2

    # -- shading ----------------------------------------------------------------
    def background(self, d: np.ndarray) -> np.ndarray:
        if self.cube is None:
            return np.broadcast_to(np.asarray(self.scene.background.color, np.float64), d.shape).copy()
        return self.cube_lookup(d)

    def cube_lookup(self, d: np.ndarray) -> np.ndarray:
        d = normalize(d)
        out = np.zeros_like(d)
        ax = np.abs(d)
        xm = (ax[:, 0] >= ax[:, 1]) & (ax[:, 0] >= ax[:, 2])
        ym = ~xm & (ax[:, 1] >= ax[:, 0]) & (ax[:, 1] >= ax[:, 2])
        zm = ~xm & ~ym
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            cases = [  # the course's CubeMap::getTexel, face by face
                (xm & (x > 0), 1, (z / x + 1) * 0.5, (y / x + 1) * 0.5),
                (xm & (x < 0), 0, (z / x + 1) * 0.5, 1 - (y / x + 1) * 0.5),
                (ym & (y > 0), 2, (x / y + 1) * 0.5, (z / y + 1) * 0.5),
                (ym & (y < 0), 3, 1 - (x / y + 1) * 0.5, 1 - (z / y + 1) * 0.5),
                (zm & (z > 0), 4, 1 - (x / z + 1) * 0.5, (y / z + 1) * 0.5),
                (zm & (z < 0), 5, (x / z + 1) * 0.5, 1 - (y / z + 1) * 0.5),
            ]
        n = self.cube.shape[1]
        for mask, face, u, v in cases:
            fx, fy = u[mask] * n, (1 - v[mask]) * n
            ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
            alpha, beta = (fx - ix)[:, None], (fy - iy)[:, None]

            def px(i, j, face=face):
                return self.cube[face, np.clip(j, 0, n - 1), np.clip(i, 0, n - 1)]

            out[mask] = ((1 - alpha) * (1 - beta) * px(ix, iy) + alpha * (1 - beta) * px(ix + 1, iy)
                         + (1 - alpha) * beta * px(ix, iy + 1) + alpha * beta * px(ix + 1, iy + 1)) / 255.0
        return out

    def trace(self, o, d, bounces: int, shadows: bool, tmin: float = 0.0) -> np.ndarray:
        hits = self.intersect(o, d, tmin)
        color = self.background(d)
        hit = np.isfinite(hits.t)
        if not hit.any():
            return color
        idx = np.nonzero(hit)[0]
        p = o[idx] + hits.t[idx, None] * d[idx]
        n = hits.normal[idx]
        mats = [self.scene.materials[k] for k in hits.material[idx]]
        kd = np.array([m.diffuse for m in mats])
        ks = np.array([m.specular for m in mats])
        s = np.array([m.shininess for m in mats])
        local = np.asarray(self.scene.background.ambient) * kd
        epsilon = self.epsilons[hits.index[idx]]
        r = d[idx] - 2 * np.sum(d[idx] * n, -1, keepdims=True) * n
        for light in self.scene.lights:
            if isinstance(light, DirectionalLight):
                to_light = np.broadcast_to(-normalize(np.asarray(light.direction, np.float64)), p.shape)
                dist = np.full(len(p), np.inf)
                lc = np.broadcast_to(np.asarray(light.color, np.float64), p.shape)
            else:
                delta = np.asarray(light.position, np.float64) - p
                dist = np.linalg.norm(delta, axis=-1)
                to_light = delta / dist[:, None]
                lc = np.asarray(light.color, np.float64) / (light.falloff * dist[:, None] ** 2)
            lit = np.ones(len(p), bool)
            if shadows:
                blocker = self.intersect(p, to_light, epsilon)
                lit = blocker.t >= dist - epsilon
            diffuse = np.maximum(np.sum(to_light * n, -1), 0)[:, None] * lc * kd
            cos_r = np.maximum(np.sum(to_light * r, -1), 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                spec = np.where(s == 0, 1.0, np.where(cos_r > 0, cos_r ** s, 0.0))[:, None] * lc * ks
            local += np.where(lit[:, None], diffuse + spec, 0.0)
        if bounces > 0:
            mirror = np.max(ks, -1) > 0
            if mirror.any():
                sub = np.nonzero(mirror)[0]
                local[sub] += ks[sub] * self.trace(p[sub], r[sub], bounces - 1, shadows, epsilon[sub])
        color[idx] = local
        return color

    def render(self, width: int, height: int, bounces: int = 0, shadows: bool = False):
        """(beauty, depth, normal) images, (H, W, 3), (H, W), (H, W, 3)."""
        o, d = self.camera_rays(width, height)
        with np.errstate(all="ignore"):  # misses compute with t = inf and are masked out
            beauty = self.trace(o, d, bounces, shadows)
            first = self.intersect(o, d, 0.0)
        depth = np.where(np.isfinite(first.t), first.t, 0.0)
        return (beauty.reshape(height, width, 3), depth.reshape(height, width),
                first.normal.reshape(height, width, 3))

"""First-hit methods: the AOVs ``albedo``, ``normal``, ``depth`` and the
rasterizer-like ``raster`` (lecture, 'Direct vs Rasterization').

=================  ==========================================================
``albedo``         first-hit albedo (Lambertian albedo, else the material's
                   reflectance tint, else 1)
``normal``         first-hit world shading normal, facing the camera
``depth``          first-hit distance from the camera (0 on a miss)
``raster``         first hit shaded like a rasterizer: emission plus each area
                   light as an unshadowed point light at its centre (one ray
                   per sample, no shadows, no bounces)
=================  ==========================================================

Each is one function of the first hit, registered with :func:`aov_method`:
a new AOV is one such function and one registration line (docs/integrators.md).
"""
from __future__ import annotations

from functools import partial

import numpy as np

from .film import BatchJob, BatchResult, camera_result
from .registry import Method, register
from .stream import camera_rays

__all__ = ["FirstHit", "aov_method", "run_first_hit_batch"]


class FirstHit:
    """The first hits of a batch of camera rays, for AOV functions.

    Attributes
    ----------
    scene, tracer
    o, d : ndarray, shape (n, 3)
        Ray origins and unit directions.
    rows : ndarray of int
        The rays that hit something.
    prim, t, p : ndarray
        Primitive, distance and point of those hits (``p`` shape (m, 3)).
    """

    def __init__(self, scene, tracer, o, d):
        self.scene, self.tracer, self.o, self.d = scene, tracer, o, d
        hit = tracer.intersect(o, d)
        self.rows = np.flatnonzero(hit.prim >= 0)
        self.prim, self.t = hit.prim[self.rows], hit.t[self.rows]
        self.p = o[self.rows] + self.t[:, None] * d[self.rows]

    @property
    def n(self) -> int:
        return self.o.shape[0]

    def shading_normals(self) -> np.ndarray:
        """Geometric normals of the hits, flipped to face the camera (m, 3)."""
        n_g = self.tracer.normals(self.prim, self.p)
        facing = np.einsum("ij,ij->i", n_g, self.d[self.rows]) < 0.0
        return np.where(facing[:, None], n_g, -n_g)

    def albedo(self) -> np.ndarray:
        """Albedo AOV of the hit materials (m, 3)."""
        table = np.array([_material_albedo(m) for m in self.scene.materials]).reshape(-1, 3)
        return np.take(table, np.take(self.scene.prim_material, self.prim), axis=0)


def _material_albedo(material) -> np.ndarray:
    """Albedo AOV of a material: Lambertian albedo, else its reflectance tint."""
    for attr in ("albedo", "reflectance"):
        if hasattr(material, attr):
            return np.broadcast_to(np.asarray(getattr(material, attr), dtype=np.float64), (3,))
    return np.ones(3)


def _depth(h: FirstHit) -> np.ndarray:
    return np.repeat(h.t[:, None], 3, axis=1)


def _normal(h: FirstHit) -> np.ndarray:
    return h.shading_normals()


def _albedo(h: FirstHit) -> np.ndarray:
    return h.albedo()


def _raster(h: FirstHit) -> np.ndarray:
    scene = h.scene
    n_s = h.shading_normals()
    value = scene.emission(h.prim, h.p, h.tracer.normals(h.prim, h.p), h.d[h.rows])
    alb = h.albedo()
    area, normal = scene.light_area, scene.light_normal
    for li in range(scene.n_lights):
        c = scene.light_origin[li] + 0.5 * (scene.light_edge1[li] + scene.light_edge2[li])
        v = c - h.p
        r2 = np.einsum("ij,ij->i", v, v)
        w = v / np.sqrt(r2)[:, None]
        cos_s = np.maximum(np.einsum("ij,ij->i", w, n_s), 0.0)
        cos_l = np.maximum(-w @ normal[li], 0.0)
        e = scene.light_radiance[li] * area[li]
        value += (alb / np.pi) * e[None, :] * (cos_s * cos_l / r2)[:, None]
    return value


def _raster_miss(h: FirstHit, miss) -> np.ndarray:
    return h.scene.environment.radiance(h.d[miss])


def run_first_hit_batch(shade, job: BatchJob, miss=None) -> BatchResult:
    """``run_batch`` of a first-hit method: ``shade(FirstHit) -> (m, 3)`` at the hits,
    ``miss(FirstHit, rows) -> (k, 3)`` for rays that hit nothing (default 0)."""
    n = job.n_pixels * job.spp
    _, o, d, _ = camera_rays(job)
    o = np.ascontiguousarray(o)
    h = FirstHit(job.scene, job.tracer, o, d)
    out = np.zeros((n, 3))
    if miss is not None and job.scene.environment is not None and h.rows.size < n:
        rows = np.flatnonzero(~np.isin(np.arange(n), h.rows))
        out[rows] = miss(h, rows)
    if h.rows.size:
        out[h.rows] = shade(h)
    return camera_result(job, out, n, "first-hit method")


def aov_method(name: str, shade, summary: str, miss=None, lecture=None) -> Method:
    """A first-hit :class:`~mcvar.integrators.registry.Method` from one shading function
    ``shade(h: FirstHit) -> (m, 3)`` (and optionally ``miss(h, rows) -> (k, 3)``)."""
    return Method(name, "first_hit", partial(run_first_hit_batch, shade, miss=miss), summary,
                  uses_max_depth=False, lecture=lecture)


register(aov_method("albedo", _albedo, "first-hit albedo (AOV)"))
register(aov_method("normal", _normal, "first-hit shading normal facing the camera (AOV)"))
register(aov_method("depth", _depth, "first-hit distance from the camera, 0 on a miss (AOV)"))
register(aov_method("raster", _raster, "first hit shaded by each light as an unshadowed point light",
                    miss=_raster_miss, lecture=("no", "no")).replace(
    chart_row="Rasterization",
    theory=("no", "no", "one unshadowed bounce: no sample count brings back the missing shadows and "
                        "interreflections")))

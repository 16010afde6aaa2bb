"""Scenes with many triangles that render the image of a coarse one (layer 4).

:func:`subdivide` cuts every non-emitting triangle of a scene into ``k^2``
congruent pieces (midpoint-style subdivision of the barycentric grid), so the
surfaces, their materials and orientation are unchanged: the image is the
coarse scene's in expectation, while the tracer sees ``k^2`` times the
triangles. It is how the cost of intersection is measured against the number
of triangles (``benchmarks/bench_triangles.py``) and how the BVH is tested
against brute force on large scenes.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ._validation import check_count

__all__ = ["subdivide", "subdivide_triangle"]


def subdivide_triangle(tri, k: int) -> np.ndarray:
    """The ``k^2`` triangles ``(k^2, 3, 3)`` of the grid ``v0 + (i e1 + j e2) / k`` of ``tri`` (3, 3).

    Every piece keeps the orientation of ``cross(v1 - v0, v2 - v0)``.
    """
    k = check_count(k, "k")
    tri = np.asarray(tri, dtype=np.float64)
    v0, e1, e2 = tri[0], (tri[1] - tri[0]) / k, (tri[2] - tri[0]) / k
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (i + j) <= k - 1
    down = (i + j) <= k - 2
    iu, ju = i[up], j[up]
    idn, jdn = i[down], j[down]

    def p(a, b):
        return v0 + a[:, None] * e1 + b[:, None] * e2

    ups = np.stack([p(iu, ju), p(iu + 1, ju), p(iu, ju + 1)], axis=1)
    downs = np.stack([p(idn + 1, jdn), p(idn + 1, jdn + 1), p(idn, jdn + 1)], axis=1)
    return np.concatenate([ups, downs])


def subdivide(scene, k: int):
    """``scene`` with every triangle that emits nothing cut into ``k^2`` pieces.

    Emitting triangles, spheres, lights, materials and the camera are kept;
    per-primitive tables (material, emission, light, group) are repeated for
    the pieces. ``k = 1`` returns an equal scene.
    """
    k = check_count(k, "k")
    n_tri = scene.n_triangles
    emits = np.any(scene.prim_emission[:n_tri] > 0, axis=1)
    pieces = [scene.triangles[t][None] if emits[t] else subdivide_triangle(scene.triangles[t], k)
              for t in range(n_tri)]
    reps = np.array([p.shape[0] for p in pieces], dtype=np.int64)
    src = np.concatenate([np.repeat(np.arange(n_tri), reps), n_tri + np.arange(scene.n_spheres)])
    tables = {key: np.take(getattr(scene, key), src, axis=0)
              for key in ("prim_material", "prim_emission", "prim_two_sided_emission", "prim_light",
                          "prim_group")}
    return dataclasses.replace(scene, name=f"{scene.name}-x{k * k}", triangles=np.concatenate(pieces),
                               **tables)

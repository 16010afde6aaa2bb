"""Emitters: the one place that samples lights, and the densities that go with it.

* Next-event estimation (:meth:`Emitters.sample_li`, pbrt-v4's
  ``SampleLi``): for shading points, one emitter (chosen uniformly among the
  area lights and the environment) and a point on it (uniform by area on a
  parallelogram, :mod:`mcvar.envmap`'s sampling for the environment), with
  the solid-angle density ``p_A r^2 / cos theta_l`` (lecture 'Light
  Sampling'; :func:`mcvar.warps.area_to_solid_angle_pdf`). Its partner
  :meth:`Emitters.pdf_li` gives that density for an emitter *hit* by BSDF
  sampling (the MIS weight of emission found by chance).
* Light subpaths (:func:`sample_le`, :func:`pdf_le`, pbrt-v4's
  ``SampleLe``/``PDF_Le``): a point uniform by area on an area light and a
  cosine-weighted direction about its emitting normal, for light tracing
  and bidirectional methods.
"""
from __future__ import annotations

import numpy as np

from ..geometry import Frame
from ..warps import (area_to_solid_angle_pdf, square_to_cosine_hemisphere,
                     square_to_cosine_hemisphere_pdf)

__all__ = ["Emitters", "sample_le", "pdf_le"]


def _dot(a, b):
    return np.einsum("ij,ij->j", a, b)


class Emitters:
    """Per-scene tables of the emitters next-event estimation samples.

    Parameters
    ----------
    scene : mcvar.scene.Scene

    Attributes
    ----------
    n_emitters : int
        Area lights plus one for an environment.
    select_pdf : float
        ``1 / n_emitters`` (uniform choice), 0 without emitters.
    single_quad : bool
        One parallelogram light and nothing else: sampling is one
        ``(3, 3) @ [1; u0; u1]`` product.
    """

    def __init__(self, scene):
        self.scene = scene
        self.n_lights = scene.n_lights
        self.env = scene.environment
        self.n_emitters = self.n_lights + (1 if self.env is not None else 0)
        self.select_pdf = 1.0 / self.n_emitters if self.n_emitters else 0.0
        self.light_area = scene.light_area
        self.light_normal = scene.light_normal
        # per light: the affine map [o e1 e2] (3, 3) and normal, SoA-friendly
        self.affine = np.stack([scene.light_origin, scene.light_edge1, scene.light_edge2], axis=2)  # (L, 3, 3)
        self.normal_soa = np.ascontiguousarray(self.light_normal.T)          # (3, L)
        self.radiance_soa = np.ascontiguousarray(scene.light_radiance.T)     # (3, L)
        self.pdf_area = self.select_pdf / self.light_area if self.n_lights else np.zeros(0)
        self.single_quad = self.n_lights == 1 and self.env is None

    # -- next-event estimation -------------------------------------------------

    def choose(self, u_sel, m: int) -> np.ndarray:
        """Emitter index of ``m`` samples from ``u_sel`` in [0, 1] (None with one
        emitter): lights ``0 .. L-1``, then ``L`` = the environment."""
        n_em = self.n_emitters
        if n_em <= 1:
            return np.zeros(m, dtype=np.int64)
        return np.minimum((np.asarray(u_sel) * n_em).astype(np.int64), n_em - 1)

    def sample_li(self, p, u, u_sel):
        """An emitter sample for every shading point (structure-of-arrays).

        Parameters
        ----------
        p : ndarray, shape (3, m)
            Shading points.
        u : ndarray, shape (2, m)
            The point on the light (parallelogram coordinates) or the
            environment's 2-D sample.
        u_sel : ndarray, shape (m,), or None
            Chooses the emitter (:meth:`choose`); None with a single emitter.

        Returns
        -------
        w : ndarray, shape (3, m)
            Unit direction from ``p`` to the sample.
        dist : ndarray, shape (m,)
            Distance (inf for the environment).
        le : ndarray, shape (3, m)
            Radiance emitted towards ``p`` (0 from the back of a light).
        pdf : ndarray, shape (m,)
            Solid-angle density of ``w`` including the emitter choice; 0
            where the sample cannot contribute (back side, edge-on).
        light : ndarray of int, shape (m,)
            Light index, -1 for the environment (for shadow keys).
        """
        m = p.shape[1]
        if self.single_quad:
            return self._area(p, u, None) + (np.zeros(m, dtype=np.int64),)
        k = self.choose(u_sel, m)
        w = np.zeros((3, m))
        w[1] = 1.0
        dist = np.full(m, np.inf)
        le = np.zeros((3, m))
        pdf = np.zeros(m)
        on_light = k < self.n_lights
        if self.n_lights and np.any(on_light):
            sel = np.flatnonzero(on_light)
            w[:, sel], dist[sel], le[:, sel], pdf[sel] = self._area(p[:, sel], u[:, sel], k[sel])
        if self.env is not None and not np.all(on_light):
            sel = np.flatnonzero(~on_light)
            w_env, pdf_env = self.env.sample(u[:, sel].T)
            w[:, sel] = w_env.T
            le[:, sel] = self.env.radiance(w_env).T
            pdf[sel] = self.select_pdf * pdf_env
        return w, dist, le, pdf, np.where(on_light, k, -1)

    def _area(self, p, u, li):
        """Uniform points on lights ``li`` (None: the single light) seen from ``p``, SoA."""
        m = p.shape[1]
        uh = np.empty((3, m))
        uh[0] = 1.0
        uh[1:] = u
        if li is None:
            x = self.affine[0] @ uh
            n_l = self.normal_soa[:, :1]
            pa = self.pdf_area[0]
            le = np.broadcast_to(self.radiance_soa[:, :1], (3, m))
        else:
            x = np.einsum("mij,jm->im", np.take(self.affine, li, axis=0), uh)
            n_l = np.take(self.normal_soa, li, axis=1)
            pa = np.take(self.pdf_area, li)
            le = np.take(self.radiance_soa, li, axis=1)
        v = x - p
        d2 = _dot(v, v)
        r = np.sqrt(d2)
        w = v / np.maximum(r, 1e-300)
        cos_l = -_dot(np.broadcast_to(n_l, w.shape), w)
        front = cos_l > 0.0
        # area density to solid angle (area_to_solid_angle_pdf's formula): p_A r^2 / cos_l
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = np.where(front, pa * d2 / cos_l, 0.0)
        if not np.all(front):
            le = np.where(front, le, 0.0)
        return w, r, le, pdf

    def pdf_li(self, prim, origins, points) -> np.ndarray:
        """Solid-angle density with which :meth:`sample_li` draws emitter hits.

        Parameters
        ----------
        prim : ndarray of int, shape (n,)
            Primitives hit (those without a light get 0: NEE never samples them).
        origins, points : ndarray, shape (n, 3)
            Where the rays started and the hit points.
        """
        light = np.take(self.scene.prim_light, prim)
        pdf = np.zeros(prim.shape[0])
        is_light = light >= 0
        if np.any(is_light):
            li = light[is_light]
            pdf[is_light] = area_to_solid_angle_pdf(np.take(self.pdf_area, li), origins[is_light],
                                                    points[is_light], np.take(self.light_normal, li, axis=0))
        return pdf

    def environment_pdf(self, d) -> np.ndarray:
        """Solid-angle density with which :meth:`sample_li` draws environment directions ``d`` (n, 3)."""
        return self.select_pdf * self.env.pdf(d)


# -- light subpaths ------------------------------------------------------------

def _choose_light(scene, u0):
    n = scene.n_lights
    if n == 0:
        raise ValueError(f"scene {scene.name!r} has no area light to start light subpaths from")
    if n == 1:
        return np.zeros(u0.shape[0], dtype=np.int64), u0
    k = np.minimum((u0 * n).astype(np.int64), n - 1)
    return k, np.clip(u0 * n - k, 0.0, 1.0)


def sample_le(scene, u_pos, u_dir):
    """Start light subpaths: a point on an area light and a direction leaving it.

    The light is chosen uniformly (by ``u_pos[:, 0]``, rescaled), the point
    uniformly by area on it (``u_pos``), the direction cosine-weighted about
    its emitting normal (``u_dir``, Malley's method).

    Parameters
    ----------
    scene : mcvar.scene.Scene
        With at least one area light (the environment is not sampled here).
    u_pos, u_dir : ndarray, shape (n, 2)
        Uniform numbers in [0, 1]^2.

    Returns
    -------
    points, directions, normals : ndarray, shape (n, 3)
        Point on the light, unit direction leaving it, the light's emitting normal.
    le : ndarray, shape (n, 3)
        Emitted radiance along ``directions``.
    pdf_pos : ndarray, shape (n,)
        Area density of the point, including the light choice: ``1 / (L A_k)``.
    pdf_dir : ndarray, shape (n,)
        Solid-angle density of the direction: ``cos theta / pi``.
    light : ndarray of int, shape (n,)
        Index of the light.

    Notes
    -----
    The emitted power estimate of one sample is ``le cos / (pdf_pos
    pdf_dir) = pi L A_k Le`` (pbrt-v4, section 12.5 ``SampleLe``).
    """
    u_pos = np.array(u_pos, dtype=np.float64).reshape(-1, 2)
    u_dir = np.asarray(u_dir, dtype=np.float64).reshape(-1, 2)
    if u_pos.shape != u_dir.shape:
        raise ValueError(f"u_pos and u_dir must both be (n, 2); got {u_pos.shape} and {u_dir.shape}")
    k, u_pos[:, 0] = _choose_light(scene, u_pos[:, 0])
    o = np.take(scene.light_origin, k, axis=0)
    points = o + u_pos[:, :1] * np.take(scene.light_edge1, k, axis=0) \
        + u_pos[:, 1:] * np.take(scene.light_edge2, k, axis=0)
    normals = np.take(scene.light_normal, k, axis=0)
    local = square_to_cosine_hemisphere(u_dir)
    directions = Frame(normals).to_world(local)
    pdf_pos = 1.0 / (scene.n_lights * np.take(scene.light_area, k))
    pdf_dir = square_to_cosine_hemisphere_pdf(local)
    le = np.where((pdf_dir > 0.0)[:, None], np.take(scene.light_radiance, k, axis=0), 0.0)
    return points, directions, normals, le, pdf_pos, pdf_dir, k


def pdf_le(scene, light, directions):
    """Densities with which :func:`sample_le` starts on ``light`` (n,) leaving along ``directions`` (n, 3).

    Returns ``(pdf_pos, pdf_dir)``: ``1 / (L A_k)`` per unit area and
    ``max(cos theta, 0) / pi`` per steradian (0 behind the light).
    """
    light = np.asarray(light, dtype=np.int64).reshape(-1)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if scene.n_lights == 0:
        raise ValueError(f"scene {scene.name!r} has no area light")
    cos = np.einsum("ij,ij->i", np.take(scene.light_normal, light, axis=0), directions)
    return 1.0 / (scene.n_lights * np.take(scene.light_area, light)), np.maximum(cos, 0.0) / np.pi

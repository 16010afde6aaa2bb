"""Where a path vertex chooses its next direction: :func:`sample_directions`.

Both wavefront loops, the general one (:mod:`mcvar.integrators.path`) and
the Lambertian kernel (:mod:`mcvar.integrators.lambertian`), call
:func:`sample_directions` once per bounce with a :class:`Vertex` (the
shading frames and what the materials need) and the paths' sample stream,
and get :class:`Directions` back: world directions, sampling weights
``f cos / p``, solid-angle densities and delta flags. This module is the
seam for another way of choosing directions (path guiding, a learned
mixture, ...): the loops use nothing else, and the MIS weight of emission
found along the new direction uses the density returned here (the
estimator stays unbiased for any density that is positive wherever
``f cos`` is, Veach 1997, sec. 9.2).

Today: BSDF sampling (``material.sample(wo, u, return_delta=True)``, one
call per material slice) and, for the Lambertian kernel's scenes, the same
distribution written out (Malley's method: ``p = cos theta / pi``, weight
``albedo``). Both read vertex ``k``'s :data:`~mcvar.integrators.stream.BSDF`
columns.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..warps import _square_to_cosine_hemisphere_unchecked
from .stream import BSDF, SampleStream

__all__ = ["Vertex", "Directions", "sample_directions"]


@dataclass
class Vertex:
    """The shading points of a wavefront at vertex ``k``, SoA ``(3, m)``.

    Attributes
    ----------
    k : int
        The vertex (reached by segment ``k``).
    idx : ndarray of int, shape (m,)
        The paths' rows in the sample stream.
    frame : tuple of three (3, m) arrays
        Shading frames ``(s, n, t)`` (local +y is ``n``).
    wo_local : ndarray (3, m) or None
        General loop: ``wo`` in the local frame (normal flipped towards it for
        two-sided materials).
    groups, materials : list of (material, start, end), tuple of BSDFs, or None
        General loop: the rows are sorted by material; ``materials[mi]``
        shades rows ``start:end``.
    sgn : ndarray (m,) or None
        Lambertian kernel: ``sign(wo . n)`` (the frame's normal is not flipped;
        0 where ``wo`` grazes the surface).
    albedo : ndarray (3, T) or None
        Lambertian kernel: the albedo of every triangle (its presence selects
        the written-out cosine sampling), looked up at ``prim``.
    prim : ndarray of int (m,) or None
        Lambertian kernel: the triangle each point lies on.
    """

    k: int
    idx: np.ndarray
    frame: tuple
    wo_local: np.ndarray | None = None
    groups: list | None = None
    materials: tuple | None = None
    sgn: np.ndarray | None = None
    albedo: np.ndarray | None = None
    prim: np.ndarray | None = None


@dataclass
class Directions:
    """What :func:`sample_directions` returns, SoA.

    Attributes
    ----------
    wi : ndarray (3, m)
        Unit world directions.
    weight : ndarray (3, m)
        ``f cos / p`` (0: the sample failed; the path's throughput becomes 0).
    pdf : ndarray (m,)
        Solid-angle density of ``wi``; ``inf`` where a delta lobe was sampled
        (its emission gets MIS weight 1).
    delta : ndarray of bool (m,) or None
        Where a delta lobe was sampled (None: no delta lobes).
    """

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray | None


def sample_directions(vertex: Vertex, stream: SampleStream, *, out=None) -> Directions:
    """Sample the next direction at every shading point of ``vertex``.

    Parameters
    ----------
    vertex : Vertex
    stream : SampleStream
        The paths' sample stream (vertex ``k``'s BSDF columns are read).
    out : ndarray (3, m), optional
        Written with ``wi`` (the Lambertian kernel reuses the rays' direction block).

    Returns
    -------
    Directions
    """
    if vertex.albedo is not None:
        return _cosine(vertex, stream, out)
    return _bsdf(vertex, stream, out)


def _bsdf(vertex: Vertex, stream: SampleStream, out) -> Directions:
    """BSDF sampling, one ``sample`` call per material slice."""
    m = vertex.idx.shape[0]
    u = stream.vertex(vertex.k, BSDF, 2, vertex.idx)
    wi_l = np.empty((3, m))
    weight = np.empty((3, m))
    pdf = np.empty(m)
    delta = np.zeros(m, dtype=bool)
    wo_l = vertex.wo_local
    for mi, a, b in vertex.groups:
        wi_g, weight_g, pdf_g, delta_g = vertex.materials[mi].sample(wo_l[:, a:b].T, u[:, a:b].T,
                                                                      return_delta=True)
        wi_l[:, a:b] = wi_g.T
        weight[:, a:b] = weight_g.T
        delta[a:b] = delta_g
        # per sample: a delta lobe's emission gets MIS weight 1 (pdf inf)
        pdf[a:b] = np.where(delta_g, np.inf, pdf_g)
    return Directions(_to_world(vertex.frame, wi_l[0], wi_l[1], wi_l[2], out), weight, pdf, delta)


def _cosine(vertex: Vertex, stream: SampleStream, out) -> Directions:
    """Lambertian BSDF sampling written out: ``p = |cos| / pi``, weight ``albedo``,
    on the side of the surface ``wo`` is on (arrays in the frame's precision)."""
    fs = vertex.frame[0]
    u = stream.vertex(vertex.k, BSDF, 2, vertex.idx, fs.dtype)
    x, y, z = _square_to_cosine_hemisphere_unchecked(u[0], u[1], np.float32)
    pdf = y * (1.0 / np.pi)
    ok = y > 0.0
    ok &= vertex.sgn != 0.0
    y *= vertex.sgn
    wi = _to_world(vertex.frame, x, y, z, out)
    del x, y, z
    weight = np.take(vertex.albedo, vertex.prim, axis=1)
    weight *= ok
    return Directions(wi, weight, pdf, None)


def _to_world(frame, x, y, z, out):
    """``s x + n y + t z`` (3, m), into ``out`` if given."""
    fs, fn, ft = frame
    wi = np.multiply(fs, x, out=out)
    wi += fn * y
    wi += ft * z
    return wi

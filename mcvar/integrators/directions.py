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

Today: BSDF sampling (Lambertian materials written out on all rows, every
other material's sampler called once on its rows) and, for the Lambertian kernel's scenes, the same
distribution written out (Malley's method: ``p = cos theta / pi``, weight
``albedo``). Both read vertex ``k``'s :data:`~mcvar.integrators.stream.BSDF`
columns.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bsdf import BSDF as BSDF_BASE
from ..warps import _INV_PI, _cosine_hemisphere_polar_unchecked, _square_to_cosine_hemisphere_unchecked
from .stream import BSDF, SampleStream

__all__ = ["Vertex", "Directions", "sample_directions", "unchecked", "unit64"]


@dataclass
class Vertex:
    """The shading points of a wavefront at vertex ``k``, SoA ``(3, m)``.

    Attributes
    ----------
    k : int or None
        The vertex (reached by segment ``k``); None when the stream knows each
        row's vertex (the Lambertian kernel's wavefront of paths at different depths).
    idx : ndarray of int, shape (m,)
        The paths' rows in the sample stream.
    frame : tuple of three (3, m) arrays
        Shading frames ``(s, n, t)`` (local +y is ``n``).
    wo_local : ndarray (3, m) or None
        General loop: ``wo`` in the local frame (normal flipped towards it for
        two-sided materials).
    groups, materials : list of (material, rows), tuple of BSDFs, or None
        General loop: ``materials[mi]`` shades the rows ``rows`` (an index
        array) through its BSDF methods; the rows of Lambertian materials are
        in no group (see ``diffuse``).
    sgn : ndarray (m,) or None
        Lambertian kernel: ``sign(wo . n)`` (the frame's normal is not flipped;
        0 where ``wo`` grazes the surface).
    albedo : ndarray (3, T) or None
        Lambertian kernel: the albedo of every triangle (its presence selects
        the written-out cosine sampling), looked up at ``prim``.
    prim : ndarray of int (m,) or None
        The primitive each point lies on (both loops).
    diffuse : ndarray (3, P + 1) or None
        General loop: the albedo of every primitive whose material is
        Lambertian, 0 on the others (their groups overwrite their rows):
        cosine sampling is written out for every row at once.
    stratified : slice or None
        Lambertian kernel: the rows whose BSDF numbers come from the sampler
        (a stratified set: the concentric map keeps its strata compact); the
        other rows draw iid numbers and use the cheaper polar map (the same
        density). None: every row as stratified.
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
    diffuse: np.ndarray | None = None
    stratified: slice | None = None


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
    """BSDF sampling: Lambertian materials written out on every row (Malley's
    method, :meth:`mcvar.bsdf.Lambertian.sample`'s numbers), then one call of
    each other material's sampler on its own rows (gathered, scattered back)."""
    m = vertex.idx.shape[0]
    dt = vertex.wo_local.dtype
    u = stream.vertex(vertex.k, BSDF, 2, vertex.idx, dt)
    wo_l = vertex.wo_local
    if vertex.diffuse is not None:
        # float32 paths: single-precision trigonometry, as the Lambertian kernel
        x, y, z = _square_to_cosine_hemisphere_unchecked(u[0], u[1], dt.type)
        ok = wo_l[1] > 0.0
        ok &= y > 0.0
        pdf = np.where(ok, y * _INV_PI, 0.0)
        weight = np.take(vertex.diffuse, vertex.prim, axis=1)
        weight *= ok
        wi_l = np.stack([x, y, z])
    else:
        wi_l, weight, pdf = np.empty((3, m), dt), np.empty((3, m)), np.empty(m)
    delta = np.zeros(m, dtype=bool)
    for mi, rows in vertex.groups:
        wi_g, weight_g, pdf_g, delta_g = unchecked(vertex.materials[mi], "sample")(
            unit64(np.take(wo_l, rows, axis=1)), np.take(u, rows, axis=1).T.astype(np.float64))
        wi_l[:, rows] = wi_g.T
        weight[:, rows] = weight_g.T
        delta[rows] = delta_g
        # per sample: a delta lobe's emission gets MIS weight 1 (pdf inf)
        pdf[rows] = np.where(delta_g, np.inf, pdf_g)
    return Directions(_to_world(vertex.frame, wi_l[0], wi_l[1], wi_l[2], out), weight, pdf, delta)


def unchecked(material, name: str):
    """``material``'s ``eval``, ``pdf`` or ``sample`` (with the delta mask) without
    the argument checks: :class:`mcvar.bsdf.BSDF`'s ``_eval`` ... on arrays the
    loops built themselves (the checks cost a tenth of a render); any other
    object's public method."""
    if isinstance(material, BSDF_BASE):
        return getattr(material, "_" + name)
    if name == "sample":
        return lambda wo, u: material.sample(wo, u, return_delta=True)
    return getattr(material, name)


def unit64(v):
    """SoA directions (3, m) as float64 rows (m, 3) of unit length: the
    materials' arithmetic in float64 whatever the loop's precision, and a
    float32 direction's length error (a few 1e-7 after two frame changes) is
    not left for the materials' unit-vector checks to trip on."""
    v = v.T.astype(np.float64)
    v /= np.sqrt(np.einsum("ij,ij->i", v, v))[:, None]
    return v


def _cosine(vertex: Vertex, stream: SampleStream, out) -> Directions:
    """Lambertian BSDF sampling written out: ``p = |cos| / pi``, weight ``albedo``,
    on the side of the surface ``wo`` is on (arrays in the frame's precision)."""
    fs = vertex.frame[0]
    u = stream.vertex(vertex.k, BSDF, 2, vertex.idx, fs.dtype)
    st = vertex.stratified
    if st is None or u.dtype != np.float32:
        x, y, z = _square_to_cosine_hemisphere_unchecked(u[0], u[1], np.float32)
    else:
        x, y, z = _cosine_hemisphere_polar_unchecked(u[0], u[1])
        if st.stop > st.start:
            x[st], y[st], z[st] = _square_to_cosine_hemisphere_unchecked(u[0, st], u[1, st], np.float32)
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

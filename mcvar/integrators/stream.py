"""Per-path sample streams: which random number of a path is which dimension.

A camera path reads its uniform numbers from one stream that hands out
dimensions in a fixed order (pbrt-v4's ``Sampler`` interface, Nori's
'infinite-dimensional hypercube'): column ``c`` of the stream matrix ``u``
is always the same decision of the path:

=============================  ==============================================
columns                        use
=============================  ==============================================
``0, 1``                       pixel position (camera)
``2 + 6 (k-1) + 0, 1``         vertex ``k``: the point on the light (NEE)
``2 + 6 (k-1) + 2, 3``         vertex ``k``: the BSDF sample (``u[:, 0]`` also
                               picks the lobe of layered materials)
``2 + 6 (k-1) + 4``            vertex ``k``: Russian roulette
``2 + 6 (k-1) + 5``            vertex ``k``: which emitter NEE samples
=============================  ==============================================

Vertex ``k`` is the surface point reached by segment ``k`` (``k = 1`` is the
first hit). A path of at most ``d`` segments samples vertices
``1 .. d - 1``, so it reads :func:`stream_dim` ``(d) = 2 + 6 (d - 1)``
columns; dimensions beyond the matrix come from the batch's ``rng`` (iid).
Whenever ``u`` is wide enough a path is a pure function of its row of
``u``: the property primary-sample-space Metropolis needs.

Pairs of columns ``(2j, 2j + 1)`` are the 2-D sets of
:func:`mcvar.samplers.pixel_samples` (padded: each pair randomized
independently), and every 2-D decision above is one such pair.
"""
from __future__ import annotations

import numpy as np

from ..samplers import pixel_sample_columns, pixel_samples

__all__ = ["camera_rays", "CAMERA_DIMS", "VERTEX_DIMS", "LIGHT", "BSDF", "ROULETTE", "LIGHT_SELECT",
           "SAMPLER_DIM", "WHOLE_SET_FLOATS", "stream_dim", "SampleStream", "whole_dims",
           "whole_pattern", "batch_stream"]

#: Columns of the camera (pixel position).
CAMERA_DIMS = 2
#: Columns per path vertex.
VERTEX_DIMS = 6
#: Offsets inside a vertex's columns.
LIGHT, BSDF, ROULETTE, LIGHT_SELECT = 0, 2, 4, 5
#: Columns the ``sampler`` of :func:`~mcvar.integrators.render` feeds by
#: default (camera + 3 vertices, depth 4); iid beyond.
SAMPLER_DIM = CAMERA_DIMS + 3 * VERTEX_DIMS
#: Largest whole-render sample pattern kept at once (float64 numbers: 100 MB).
WHOLE_SET_FLOATS = 6 * 2 ** 21


def stream_dim(max_depth: int | None) -> int | None:
    """Columns of ``u`` a camera path of at most ``max_depth`` segments reads (None: unbounded)."""
    if max_depth is None:
        return None
    return CAMERA_DIMS + VERTEX_DIMS * max(int(max_depth) - 1, 0)


class SampleStream:
    """Dimensions of a wavefront of paths: columns of ``u`` while they last, then ``rng``.

    Parameters
    ----------
    u : ndarray, shape (n, D), or None
        The paths' sample matrix (rows in path order); None: everything from ``rng``.
    rng : numpy.random.Generator
        Dimensions beyond ``u``'s columns (iid).
    camera : bool
        True: ``u`` starts with the camera columns (the layout above); False:
        it starts at vertex 1 (:func:`~mcvar.integrators.trace_paths`).
    """

    def __init__(self, u, rng, *, camera: bool = True):
        self.rng = rng
        self._uT32 = None
        if u is None:
            self.uT = None
            self.width = 0
        else:
            u = np.asarray(u, dtype=np.float64)
            self.uT = np.ascontiguousarray(u.T)     # (D, n): a column is contiguous
            self.width = u.shape[1]
        self.base = 0 if camera else -CAMERA_DIMS

    def _table(self, dtype):
        """``u``'s columns (D, n) in ``dtype`` (a float32 copy is made once)."""
        if dtype == np.float64:
            return self.uT
        if self._uT32 is None:
            self._uT32 = self.uT.astype(np.float32)
        return self._uT32

    def columns(self, first: int, count: int, idx, dtype=np.float64) -> np.ndarray:
        """Dimensions ``first .. first + count - 1`` of paths ``idx``: shape (count, m).

        ``dtype=np.float32`` (the Lambertian kernel, whose path state is
        float32): ``u``'s columns rounded to float32 (values within 2^-25 of 1
        become 1.0, which every warp here accepts) and draws from ``rng`` in
        float32 (in [0, 1)); a path is still a pure function of its row of ``u``.
        """
        m = np.shape(idx)[0]
        a = first + self.base
        have = max(0, min(count, self.width - a)) if a >= 0 else 0
        if have == count:
            return np.take(self._table(dtype)[a:a + count], idx, axis=1)
        out = np.empty((count, m), dtype)
        if have:
            out[:have] = np.take(self._table(dtype)[a:a + have], idx, axis=1)
        out[have:] = self.rng.random((count - have, m), dtype=dtype)
        return out

    def vertex(self, k: int, offset: int, count: int, idx, dtype=np.float64) -> np.ndarray:
        """``count`` dimensions at ``offset`` (:data:`LIGHT` ...) of vertex ``k`` of paths ``idx``."""
        return self.columns(CAMERA_DIMS + VERTEX_DIMS * (k - 1) + offset, count, idx, dtype)


def whole_dims(sampler: str, n_pix: int, spp: int, n_batches: int, dim: int) -> int:
    """Leading columns of the whole-render pattern :func:`whole_pattern` keeps (even, 0: none)."""
    if sampler == "random" or n_batches == 1:
        return 0
    dims = min(dim, WHOLE_SET_FLOATS // (n_pix * spp)) // 2 * 2
    return dims if dims >= 2 else 0


def whole_pattern(sampler: str, n_pix: int, spp: int, n_batches: int, dim: int, rng):
    """One stratified pattern per pixel over all spp, for the batches to slice.

    For a stratified or QMC sampler, each pixel's whole ``spp``-point set is
    drawn once for the leading dimensions that fit :data:`WHOLE_SET_FLOATS`
    (an even number, at most ``dim``: :func:`whole_dims`), and the batches
    trace consecutive slices of it (batch ``b`` of ``s`` spp starting at
    sample ``a``: ``pattern[:, a:a + s]``), so a 256-spp Sobol render is one
    256-point net per pixel, not sixteen 16-point ones (measured at 64 x 64:
    MSE 7.0e-5 -> 3.0e-5 for path tracing). Partial sets stay unbiased (each
    point is marginally uniform), so an interrupted render is too. Returns
    an ``(n_pix, spp, dims)`` array, or None (``random``: iid has nothing to
    keep; a single batch; nothing fits).
    """
    dims = whole_dims(sampler, n_pix, spp, n_batches, dim)
    return pixel_samples(sampler, n_pix, spp, dim=dims, rng=rng) if dims else None


def batch_stream(sampler: str, n_pix: int, spp: int, dim: int, whole, rng):
    """One batch's sample matrix ``(n_pix spp, dim)`` in path order, or None.

    None for ``random`` (every dimension from the batch's ``rng``) and for
    ``dim = 0`` (a method that reads no sampler columns). ``whole``: this
    batch's slice of :func:`whole_pattern` (its leading columns), or None;
    the remaining columns are this batch's own padded sets
    (:func:`mcvar.samplers.pixel_sample_columns`, drawn from ``rng``, the
    values of :func:`~mcvar.samplers.pixel_samples` laid out as rows, so
    the matrix returned is a transposed view: a dimension is contiguous).
    """
    if sampler == "random" or dim == 0:
        return None
    have = 0 if whole is None else whole.shape[2]
    if have >= dim:
        return np.ascontiguousarray(whole[:, :, :dim]).reshape(n_pix * spp, dim)
    if whole is None:
        return pixel_sample_columns(sampler, n_pix, spp, dim=dim, rng=rng).T
    # drop the first pair of the batch's own sets: it keeps the sampler's
    # order (pixel_samples' notes) and would correlate with the whole set's
    # first pair; the later pairs are shuffled. Written as rows (dim, n), the
    # matrix returned is their transpose, like the case without a whole set.
    n = n_pix * spp
    out = np.empty((dim, n))
    out[:have] = np.moveaxis(whole, 2, 0).reshape(have, n)
    out[have:] = pixel_sample_columns(sampler, n_pix, spp, dim=dim - have + 2, rng=rng)[2:]
    return out.T


def camera_rays(job, *, soa: bool = False):
    """The camera rays of a batch: ``(pixel, origins, directions, stream)``.

    Path ``i`` of the batch belongs to pixel ``job.pixel_index[i // spp]``
    (pixel-major: all pixels, or the batch's ``job.pixels``) and
    takes its position in the pixel from columns 0-1 of its sample stream.
    Directions are ``(n, 3)``, or ``(3, n)`` with ``soa=True`` (the wavefront
    layout); origins broadcast to the same shape (a read-only view).
    """
    n = job.n_pixels * job.spp
    pixel = np.repeat(job.pixel_index, job.spp)
    stream = SampleStream(job.u, job.rng)
    offsets = stream.columns(0, CAMERA_DIMS, np.arange(n))
    cam = job.scene.camera
    if soa:
        d = cam.ray_directions_soa(job.res, pixel, offsets.T)
        return pixel, np.broadcast_to(cam.position[:, None], d.shape), d, stream
    d = cam.ray_directions(job.res, pixel, offsets.T)
    return pixel, np.broadcast_to(cam.position, d.shape), d, stream

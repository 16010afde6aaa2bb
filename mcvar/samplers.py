"""Point sets in the unit square: the lecture's samplers (layer 1).

Every sampler has the signature ``name(n, *, rng=None, **options)`` and returns
an ``(n, 2)`` float64 array (``(n, dim)`` where a ``dim`` option exists) with
every coordinate in [0, 1): strictly below 1, so ``floor(u * k)`` never indexes
past an array. ``n = 0`` gives an empty ``(0, d)`` array (as
:mod:`scipy.stats.qmc`); a call needing more than :data:`MAX_BYTES` of memory
is refused with a ``ValueError`` before anything is allocated. The same
``rng`` (seed or Generator state) gives the same points. :data:`SAMPLERS`
maps the names to :class:`Sampler` records (the function and everything the
rest of mcvar needs to know about it; a record is called like its function);
:func:`get_sampler` looks a function up, :func:`register_sampler` adds one;
:func:`pixel_samples` draws an independently randomized set per pixel,
vectorised over pixels, for the tracer.

The lecture's slides "Uniform / Random / Jittered / N-Rooks / Multi-Jittered /
Hammersley / Low-Discrepancy / Blue Noise Sampling" are implemented here; their
discrepancy and spectra are measured by :mod:`mcvar.discrepancy`.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import qmc

from ._validation import MEMORY_BUDGET, as_points, as_rng, check_bool, check_choice, check_count, check_positive

__all__ = [
    "Sampler",
    "SAMPLERS",
    "DETERMINISTIC",
    "get_sampler",
    "sampler_record",
    "register_sampler",
    "shifted_pixel_sets",
    "pixel_samples",
    "pixel_sample_columns",
    "cranley_patterson",
    "digital_shift",
    "radical_inverse",
    "random",
    "grid",
    "jittered",
    "n_rooks",
    "multi_jittered",
    "hammersley",
    "halton",
    "sobol",
    "blue_noise",
]

#: Largest float64 below 1: every sampler clamps to it so that u < 1 holds
#: even where ``(k - 1 + u) / k`` rounds up to exactly 1.0.
ONE_MINUS_EPS = float(np.nextafter(1.0, 0.0))

_FRACTION_BITS = 52  # digital shifts act on the first 52 binary digits

#: Largest working memory, in bytes, that one sampler call may allocate
#: (4 GiB). A call that would need more raises a ``ValueError`` saying how
#: much before anything is allocated, instead of dying in a ``MemoryError``
#: deep inside NumPy. Override it for the session, e.g.
#: ``mcvar.samplers.MAX_BYTES = 16 * 2**30`` (docs/conventions.md, 'Memory').
MAX_BYTES = MEMORY_BUDGET

# Peak working memory of pixel_samples, in 8-byte words per output coordinate
# (measured at most 7.0, see Sampler.words_per_coord for the generators').
_PIXEL_WORDS = 8


def _fmt_bytes(b: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if b < 1024.0 or unit == "PiB":
            return f"{b:.3g} {unit}"
        b /= 1024.0
    return f"{b:.3g} PiB"  # pragma: no cover


def _check_memory(n: int, d: int, sampler: str, *, what: str = "n", sets: int = 1) -> None:
    """ValueError before allocating if ``sets * n * d`` coordinates need more than :data:`MAX_BYTES`
    (``sampler`` names a record of :data:`SAMPLERS`, or is ``'pixel_samples'``)."""
    words = _PIXEL_WORDS if sampler == "pixel_samples" else SAMPLERS[sampler].words_per_coord
    need = 8.0 * words * float(sets) * float(n) * float(d)
    limit = MAX_BYTES
    if need > limit:
        fit = int(limit // (8 * words * sets * d))
        raise ValueError(
            f"{sampler}: {what}={n} points in {d} dimensions"
            + (f" for {sets} pixels" if sets > 1 else "")
            + f" need about {_fmt_bytes(need)} of working memory, over the limit "
            f"mcvar.samplers.MAX_BYTES = {_fmt_bytes(limit)}; use a smaller {what} (at most "
            f"{fit} fits{' at this many pixels, or render fewer pixels at a time' if sets > 1 else ''}), "
            "or draw independent batches (one per rng.spawn stream) and combine "
            "their estimates, or raise mcvar.samplers.MAX_BYTES if the machine has the memory")


def _count(n, d: int, sampler: str) -> int:
    """A sample count >= 0 (0 gives an empty ``(0, d)`` set, as scipy.stats.qmc) that fits in memory."""
    n = check_count(n, allow_zero=True)
    _check_memory(n, d, sampler)
    return n


def _empty(d: int) -> np.ndarray:
    return np.empty((0, d), dtype=np.float64)


def _below_one(x: np.ndarray) -> np.ndarray:
    return np.minimum(x, ONE_MINUS_EPS, out=x)


def _check_dim(dim, *, name: str = "dim") -> int:
    return check_count(dim, name)


def _primes(k: int) -> list[int]:
    """The first ``k`` primes (bases of the Halton sequence)."""
    primes: list[int] = []
    candidate = 2
    while len(primes) < k:
        if all(candidate % p for p in primes if p * p <= candidate):
            primes.append(candidate)
        candidate += 1
    return primes


def _integer_root(n: int, dim: int, sampler: str, name: str = "n") -> int:
    """``k`` with ``k**dim == n`` or a ValueError naming the sampler and rule."""
    k = int(round(n ** (1.0 / dim)))
    for cand in (k - 1, k, k + 1):
        if cand >= 1 and cand ** dim == n:
            return cand
    power = "perfect square" if dim == 2 else f"perfect {dim}-th power"
    below = max(int(math.floor(n ** (1.0 / dim))), 1)
    raise ValueError(
        f"{name} must be a {power} for the {sampler} sampler (k**{dim} points on a k x ... x k grid); "
        f"got {name}={n} (nearest: {below ** dim} or {(below + 1) ** dim})")


# --------------------------------------------------------------------------
# Randomizations shared by every deterministic pattern
# --------------------------------------------------------------------------

def cranley_patterson(points, rng=None) -> np.ndarray:
    """Randomize a point set by one toroidal random shift (Cranley-Patterson rotation).

    Parameters
    ----------
    points : array_like, shape (n, d)
        Points in [0, 1]^d.
    rng : None, int, SeedSequence or Generator
        Source of the shift vector.

    Returns
    -------
    ndarray, shape (n, d)
        ``(points + s) mod 1`` with one ``s ~ U[0, 1)^d`` for the whole set,
        clamped below 1.

    Notes
    -----
    Each shifted point is uniform on [0, 1)^d, so any estimator averaging ``f``
    over the set is unbiased, while the set keeps its structure on the torus:
    the wrap-around L2 discrepancy is unchanged exactly, lattices stay
    lattices. It does *not* preserve the (0, m, 2)-net property of Sobol or
    Hammersley points (use :func:`digital_shift` for that).

    References
    ----------
    R. Cranley and T. N. L. Patterson, "Randomization of number theoretic
    methods for multiple integration", SIAM J. Numer. Anal. 13(6), 1976.

    Examples
    --------
    >>> p = cranley_patterson(grid(4), rng=1)
    >>> p.shape
    (4, 2)
    """
    pts = as_points(points, "points", unit=True)
    shift = as_rng(rng).random(pts.shape[1])
    return _below_one(np.mod(pts + shift, 1.0))


def digital_shift(points, rng=None) -> np.ndarray:
    """Randomize a point set by a random base-2 digital shift (XOR of binary digits).

    Parameters
    ----------
    points : array_like, shape (n, d)
        Points in [0, 1)^d (1.0 is not allowed: it has no binary fraction).
    rng : None, int, SeedSequence or Generator
        Source of the shift.

    Returns
    -------
    ndarray, shape (n, d)
        Each coordinate's first 52 binary digits XOR-ed with the digits of
        one random ``s_j ~ U[0, 1)`` per dimension.

    Notes
    -----
    XOR with a fixed digit string maps every elementary interval
    ``[a 2^-k, (a + 1) 2^-k)`` onto another one of the same size, so a
    (t, m, s)-net in base 2 stays a (t, m, s)-net, and each shifted point is
    uniform on [0, 1)^d. This is the cheapest randomization that keeps Sobol
    and Hammersley stratification (Owen 2003, section 2.3).

    References
    ----------
    A. B. Owen, "Variance with alternative scramblings of digital nets",
    ACM TOMACS 13(4), 2003.
    """
    pts = as_points(points, "points")
    if pts.size and not (np.all(pts >= 0.0) and np.all(pts < 1.0)):
        raise ValueError(f"points must lie in [0, 1)^d for a digital shift; "
                         f"got values in [{pts.min()}, {pts.max()}]")
    shift = as_rng(rng).integers(0, 2 ** _FRACTION_BITS, size=pts.shape[1], dtype=np.uint64)
    return _xor_shift(pts, shift)


def _xor_shift(points: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """XOR the 52-bit fractions of ``points`` (..., d) with integer ``shift`` (broadcast)."""
    bits = np.ldexp(points, _FRACTION_BITS).astype(np.uint64)
    return np.ldexp((bits ^ shift).astype(np.float64), -_FRACTION_BITS)


# --------------------------------------------------------------------------
# Batched generators: (sets, n, d) arrays, one independent set per leading index
# --------------------------------------------------------------------------

def _random_sets(sets: int, n: int, d: int, rng) -> np.ndarray:
    return rng.random((sets, n, d))


def _grid_base(n: int, d: int) -> np.ndarray:
    k = _integer_root(n, d, "grid")
    idx = np.indices((k,) * d).reshape(d, -1).T[:, ::-1]  # x fastest, then y, ...
    return (idx + 0.5) / k


def _jittered_sets(sets: int, n: int, d: int, rng) -> np.ndarray:
    k = _integer_root(n, d, "jittered")
    idx = np.indices((k,) * d).reshape(d, -1).T[:, ::-1]
    return _below_one((idx + rng.random((sets, n, d))) / k)


def _latin_sets(sets: int, n: int, d: int, rng) -> np.ndarray:
    perms = rng.permuted(np.broadcast_to(np.arange(n), (sets, d, n)), axis=-1)
    pts = (perms + rng.random((sets, d, n))) / n
    return _below_one(np.ascontiguousarray(pts.transpose(0, 2, 1)))


def _mj_shape(n: int) -> tuple[int, int]:
    """Columns and rows (nx, ny) with nx * ny = n, as square as n allows."""
    ny = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    return n // ny, ny


def _multi_jittered_sets(sets: int, n: int, rng, correlated: bool) -> np.ndarray:
    nx, ny = _mj_shape(n)
    # cell (i, j): column i < nx, row j < ny; sample index s = j * nx + i
    i = np.arange(nx)[None, :]
    j = np.arange(ny)[:, None]
    if correlated:  # one permutation shared by all columns / all rows (Kensler 2013)
        px = rng.permuted(np.broadcast_to(np.arange(ny), (sets, ny)), axis=-1)[:, :, None]
        py = rng.permuted(np.broadcast_to(np.arange(nx), (sets, nx)), axis=-1)[:, None, :]
    else:  # an independent permutation per column and per row (Chiu et al. 1994)
        px = rng.permuted(np.broadcast_to(np.arange(ny), (sets, nx, ny)), axis=-1)
        px = px.transpose(0, 2, 1)  # px[:, j, i]: substratum of the point in row j, column i
        py = rng.permuted(np.broadcast_to(np.arange(nx), (sets, ny, nx)), axis=-1)
    pts = rng.random((sets, ny, nx, 2))  # the jitter, turned into the points in place
    pts[..., 0] += i * ny + px
    pts[..., 1] += j * nx + py
    pts /= n
    return _below_one(pts.reshape(sets, n, 2))


# --------------------------------------------------------------------------
# Radical inverse, Hammersley, Halton, Sobol
# --------------------------------------------------------------------------

def radical_inverse(index, base: int = 2, *, permutations=None) -> np.ndarray:
    """The radical inverse Phi_b(i): the base-b digits of ``i`` mirrored about the point.

    Parameters
    ----------
    index : array_like of int
        Non-negative integers ``i``.
    base : int
        Base ``b >= 2``.
    permutations : ndarray, shape (levels, base), optional
        One permutation of the digits {0, ..., b - 1} per digit level
        (scrambled radical inverse); ``levels`` digits are produced, trailing
        zero digits included, so that every output is uniform when the
        permutations are random.

    Returns
    -------
    ndarray of float64, same shape as ``index``, in [0, 1).

    Notes
    -----
    If ``i = sum_j a_j(i) b^j`` then ``Phi_b(i) = sum_j a_j(i) b^(-j-1)``
    (lecture, slide "Hammersley Sampling"). The slide's example is
    ``13 = 1101_2 -> 0.1011_2 = 1/2 + 1/8 + 1/16 = 11/16 = 0.6875``; the slide
    prints 0.6975, a typo. The digits are accumulated as an integer and scaled
    once, so base-2 values are exact.

    Examples
    --------
    >>> float(radical_inverse(13, 2))
    0.6875
    """
    b = check_count(base, "base")
    if b < 2:
        raise ValueError(f"base must be >= 2; got {b}")
    idx = np.asarray(index)
    if idx.dtype.kind not in "iu":
        raise TypeError(f"index must hold integers; got dtype {idx.dtype}")
    if idx.size and idx.min() < 0:
        raise ValueError(f"index must be >= 0; got minimum {idx.min()}")
    idx = idx.astype(np.int64)
    if permutations is None:
        levels = 0
        top = int(idx.max()) if idx.size else 0
        while top > 0:
            top //= b
            levels += 1
        perms = None
    else:
        perms = np.asarray(permutations)
        if perms.ndim != 2 or perms.shape[1] != b:
            raise ValueError(f"permutations must have shape (levels, {b}); got {perms.shape}")
        levels = perms.shape[0]
    reversed_digits = np.zeros(idx.shape, dtype=np.float64)
    scale = 1.0
    rest = idx.copy()
    for level in range(levels):
        digit = rest % b
        rest //= b
        if perms is not None:
            digit = perms[level][digit]
        reversed_digits = reversed_digits * b + digit
        scale /= b
    return _below_one(np.asarray(reversed_digits * scale, dtype=np.float64))


def _scramble_levels(base: int) -> int:
    """Digits needed for the scrambled radical inverse to reach float64 precision."""
    return int(math.ceil(53 * math.log(2) / math.log(base)))


def _radical_columns(index: np.ndarray, bases, rng, scramble: bool) -> np.ndarray:
    cols = []
    for b in bases:
        perms = None
        if scramble:
            levels = _scramble_levels(b)
            perms = rng.permuted(np.broadcast_to(np.arange(b), (levels, b)), axis=-1)
        cols.append(radical_inverse(index, b, permutations=perms))
    return np.stack(cols, axis=-1) if cols else np.empty((index.size, 0))


def hammersley(n, *, rng=None, dim: int = 2, scramble: bool = False) -> np.ndarray:
    """Hammersley points ``(i / n, Phi_2(i), Phi_3(i), ...)``, i = 0 ... n - 1.

    Parameters
    ----------
    n : int
        Number of points (the whole set depends on n: not extensible).
    rng : None, int, SeedSequence or Generator
        Used only when ``scramble``.
    dim : int
        Dimension; coordinate k >= 1 is the radical inverse in the k-th prime.
    scramble : bool
        Randomize: the first coordinate by a random base-2 digital shift, the
        others by random digit permutations per digit level. In base 2 both
        are XORs with random bits, so the (0, m, 2)-net property of n = 2^m
        points in 2D is kept.

    Notes
    -----
    Lecture slide "Hammersley Sampling": ``p_i = (i / n, Phi_2(i))``. For
    ``n = 2^m`` the 2D set is a (0, m, 2)-net in base 2: every elementary
    interval of area 1/n holds exactly one point, so its star discrepancy is
    O(log n / n). (The slide's 0.6975 for Phi_2(13) should read 0.6875, see
    :func:`radical_inverse`.)

    References
    ----------
    J. M. Hammersley, "Monte Carlo methods for solving multivariable
    problems", Ann. New York Acad. Sci. 86, 1960.

    Examples
    --------
    >>> hammersley(4)
    array([[0.  , 0.  ],
           [0.25, 0.5 ],
           [0.5 , 0.25],
           [0.75, 0.75]])
    """
    scramble = check_bool(scramble, "scramble")
    d = _check_dim(dim)
    n = _count(n, d, "hammersley")
    if n == 0:
        return _empty(d)
    i = np.arange(n)
    if scramble:
        gen = as_rng(rng)
        first = _xor_shift(i[:, None] / n, gen.integers(0, 2 ** _FRACTION_BITS, size=1, dtype=np.uint64))
        rest = _radical_columns(i, _primes(d - 1), gen, True)
    else:
        first = (i / n)[:, None]
        rest = _radical_columns(i, _primes(d - 1), None, False)
    return np.concatenate([first, rest], axis=1)


def halton(n, *, rng=None, dim: int = 2, scramble: bool = False) -> np.ndarray:
    """The Halton sequence ``(Phi_2(i), Phi_3(i), Phi_5(i), ...)``, i = 0 ... n - 1.

    Parameters
    ----------
    n : int
        Number of points (a prefix of an infinite sequence: extensible).
    rng : None, int, SeedSequence or Generator
        Used only when ``scramble``.
    dim : int
        Dimension; coordinate k uses the k-th prime base.
    scramble : bool
        Random digit permutations, one per base and digit level (the
        randomization scipy.stats.qmc.Halton also applies); removes the
        correlation between high prime bases.

    Notes
    -----
    Star discrepancy O((log n)^d / n) for every prefix.

    References
    ----------
    J. H. Halton, "On the efficiency of certain quasi-random sequences of
    points in evaluating multi-dimensional integrals", Numer. Math. 2, 1960.
    """
    scramble = check_bool(scramble, "scramble")
    d = _check_dim(dim)
    n = _count(n, d, "halton")
    if n == 0:
        return _empty(d)
    gen = as_rng(rng) if scramble else None
    return _radical_columns(np.arange(n), _primes(d), gen, scramble)


def _sobol_points(n: int, d: int, scramble: bool, rng) -> np.ndarray:
    # scipy's default 30 bits leave scrambled points on a 2^-30 grid, so every
    # estimate carries a bias of ~2^-31 that replicate error bars cannot see;
    # scrambling 52 bits randomises every binary digit a float64 in [0, 1) has.
    engine = qmc.Sobol(d, scramble=scramble, rng=rng, bits=_FRACTION_BITS if scramble else 30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # re-issued below with our stacklevel
        return engine.random(n)


def sobol(n, *, rng=None, dim: int = 2, scramble: bool = True) -> np.ndarray:
    """Sobol' points from :class:`scipy.stats.qmc.Sobol`, scrambled by default.

    Parameters
    ----------
    n : int
        Number of points; a power of 2 keeps the net property (others warn).
    rng : None, int, SeedSequence or Generator
        Source of the scrambling.
    dim : int
        Dimension (scipy supports up to 21201).
    scramble : bool
        scipy's randomization: a random linear matrix scramble plus a random
        digital shift (Matousek 1998), which keeps every (t, m, s)-net property
        and makes each point uniform. (Full nested Owen scrambling has the
        same first and second moments for many integrands but is not what
        scipy implements.) ``False`` gives the classic unscrambled sequence,
        whose first point is the origin.

    Notes
    -----
    A (t, s)-sequence in base 2: in 2D, t = 0, so every aligned block of 2^m
    points is a (0, m, 2)-net (like Hammersley, but extensible).

    References
    ----------
    I. M. Sobol', "On the distribution of points in a cube and the approximate
    evaluation of integrals", USSR Comput. Math. Math. Phys. 7(4), 1967.
    J. Matousek, "On the L2-discrepancy for anchored boxes", J. Complexity
    14(4), 1998.
    """
    scramble = check_bool(scramble, "scramble")
    d = _check_dim(dim)
    n = _count(n, d, "sobol")
    if n == 0:
        return _empty(d)
    if n & (n - 1):
        warnings.warn(f"sobol: n={n} is not a power of 2, so the points are not a (0, m, 2)-net "
                      "and lose balance", UserWarning, stacklevel=2)
    return _below_one(_sobol_points(n, d, scramble, as_rng(rng)))


# --------------------------------------------------------------------------
# Blue noise (Poisson disk by toroidal dart throwing)
# --------------------------------------------------------------------------

def _poisson_disk(n: int, rng, rho: float) -> np.ndarray:
    """n points, pairwise toroidal distance >= r, r = rho * r_max (shrunk if throwing stalls)."""
    r = rho * math.sqrt(2.0 / (math.sqrt(3.0) * n))
    pts = np.empty((0, 2))
    stalls = 0
    while pts.shape[0] < n:
        need = n - pts.shape[0]
        cand = rng.random((max(64, 16 * need), 2))
        if pts.shape[0]:
            dist, _ = cKDTree(pts, boxsize=1.0).query(cand, distance_upper_bound=r)
            cand = cand[np.isinf(dist)]
        if cand.shape[0] > 1:  # among the new darts, a later one loses against an earlier one
            pairs = cKDTree(cand, boxsize=1.0).query_pairs(r, output_type="ndarray")
            keep = np.ones(cand.shape[0], dtype=bool)
            keep[pairs[:, 1]] = False
            cand = cand[keep]
        accepted = cand[:need]
        pts = np.concatenate([pts, accepted])
        stalls = stalls + 1 if accepted.shape[0] < max(1, need // 20) else 0
        if stalls >= 5:  # near jamming: accept slightly closer points
            r *= 0.97
            stalls = 0
    return pts


def blue_noise(n, *, rng=None, radius: float = 0.7) -> np.ndarray:
    """Blue-noise points: a Poisson-disk set on the torus by dart throwing.

    Parameters
    ----------
    n : int
        Number of points (exactly n are returned).
    rng : None, int, SeedSequence or Generator
        Source of the darts.
    radius : float
        Requested relative radius ``rho = r / r_max`` in (0, 0.85], where
        ``r_max = sqrt(2 / (sqrt(3) n))`` is the spacing of n points on a
        hexagonal lattice (the densest packing). 0.7 (default) gives a clear
        blue-noise spectrum; it is also about the largest radius this dart
        thrower reaches (see the table below): asking for more gives *less*.

    Notes
    -----
    Darts are thrown in vectorised batches; a dart is kept if no accepted
    point and no earlier dart of its batch lies within ``r`` (toroidal
    distance, via :class:`scipy.spatial.cKDTree` with ``boxsize=1``). If the
    batches stall (five batches in a row each filling under 5 % of the
    missing points), ``r`` shrinks by 3 % and throwing goes on. Achieved
    relative radius (minimum toroidal distance / ``r_max``), mean [min, max]
    over 10 seeds (4 at n = 4096):

    =========  ======================  ======================  ======================
    radius     n = 64                  n = 1024                n = 4096
    =========  ======================  ======================  ======================
    0.65       0.655 [0.651, 0.661]    0.650 [0.650, 0.650]    0.650 [0.650, 0.650]
    0.70       0.700 [0.680, 0.707]    0.700 [0.700, 0.700]    0.700 [0.700, 0.700]
    0.75       0.716 [0.670, 0.751]    0.698 [0.685, 0.710]    0.692 [0.670, 0.709]
    0.80       0.720 [0.691, 0.744]    0.686 [0.668, 0.701]    0.687 [0.669, 0.699]
    0.85       0.700 [0.668, 0.717]    0.675 [0.655, 0.695]    0.684 [0.670, 0.691]
    =========  ======================  ======================  ======================

    So up to 0.7 the requested radius is met (for n >= 256 in every run;
    small sets may end a few percent below), and above about 0.72 the
    throwing jams and the 3 % steps overshoot: every request between 0.75
    and 0.85 ends near 0.67-0.72. (Maximal Poisson-disk sets, which fill
    every gap, reach about 0.75 on average; Lagae and Dutre 2008.)
    Distances are measured on the torus, so
    the set tiles without seams, Cranley-Patterson shifts keep it blue, and its
    periodogram has no boundary artefacts. The spectrum is isotropic (no
    preferred direction) with a dark centre and a bright ring at the mean
    spacing (lecture, slide "Blue Noise"; the slide's word "anisotropic"
    should read *isotropic*).

    References
    ----------
    R. L. Cook, "Stochastic sampling in computer graphics", ACM TOG 5(1), 1986.
    A. Lagae and P. Dutre, "A comparison of methods for generating Poisson
    disk distributions", Computer Graphics Forum 27(1), 2008.
    J. I. Yellott, "Spectral consequences of photoreceptor sampling in the
    rhesus retina", Science 221, 1983.
    """
    n = _count(n, 2, "blue_noise")
    rho = check_positive(radius, "radius")
    if not rho <= 0.85:
        raise ValueError(f"radius must be <= 0.85 (relative to hexagonal packing; random packings "
                         f"jam near 0.77); got {rho}")
    if n == 0:
        return _empty(2)
    return _below_one(_poisson_disk(n, as_rng(rng), rho))


# --------------------------------------------------------------------------
# The remaining public samplers (thin wrappers of the batched generators)
# --------------------------------------------------------------------------

def random(n, *, rng=None, dim: int = 2) -> np.ndarray:
    """Independent uniform points (lecture, slide "Random Sampling").

    Star discrepancy decays like n^-1/2 (law of the iterated logarithm).

    Examples
    --------
    >>> random(3, rng=7).shape
    (3, 2)
    """
    d = _check_dim(dim)
    return _random_sets(1, _count(n, d, "random"), d, as_rng(rng))[0]


def grid(n, *, rng=None, dim: int = 2) -> np.ndarray:
    """Cell centres of a k x k grid, n = k^2 (lecture, slide "Uniform Sampling").

    ``rng`` is accepted for the common signature and ignored: the grid is
    deterministic (use :func:`cranley_patterson` to randomize it). Row-major
    order, x fastest. A perfect square ``n`` is required (ValueError
    otherwise); its star discrepancy decays only like n^-1/2 because whole
    rows of points enter an anchored box together.
    """
    d = _check_dim(dim)
    n = _count(n, d, "grid")
    return _grid_base(n, d) if n else _empty(d)


def jittered(n, *, rng=None, dim: int = 2) -> np.ndarray:
    """One uniform point in each cell of a k x k grid, n = k^2 (slide "Jittered Sampling").

    Notes
    -----
    Stratified sampling: the variance of the mean of a smooth integrand falls
    like n^-2 in 2D instead of n^-1 (Mitchell 1996, "Consequences of
    stratified sampling in graphics", SIGGRAPH). ``n`` must be ``k**dim``.
    """
    d = _check_dim(dim)
    n = _count(n, d, "jittered")
    return _jittered_sets(1, n, d, as_rng(rng))[0] if n else _empty(d)


def n_rooks(n, *, rng=None, dim: int = 2) -> np.ndarray:
    """Latin hypercube ("N-rooks") points: each row and column holds exactly one point.

    Notes
    -----
    Built directly: coordinate k of point i is ``(pi_k(i) + u) / n`` with an
    independent uniform random permutation ``pi_k`` per dimension, so the
    rooks condition holds by construction, in O(n) time.

    The lecture's recipe (start on the diagonal, shuffle until no two points
    share a row or column) may never terminate: if each attempt draws the
    columns at random, it succeeds only when the draw is a permutation, with
    probability n!/n^n ~ sqrt(2 pi n) e^-n (about 2e-4 already for n = 10);
    the number of attempts is geometric, finite with probability 1 but with
    no bound on any run, and its mean n^n/n! grows exponentially. A
    procedure that swaps coordinates and checks the condition never needs to
    search at all: a permutation *is* the rooks condition.

    References
    ----------
    M. D. McKay, R. J. Beckman and W. J. Conover, "A comparison of three
    methods for selecting values of input variables in the analysis of output
    from a computer code", Technometrics 21(2), 1979.
    P. Shirley, "Discrepancy as a quality measure for sample distributions",
    Eurographics 1991.
    """
    d = _check_dim(dim)
    return _latin_sets(1, _count(n, d, "n_rooks"), d, as_rng(rng))[0]


def multi_jittered(n, *, rng=None, correlated: bool = False) -> np.ndarray:
    """Multi-jittered points: jittered on an nx x ny grid *and* N-rooks at once.

    Parameters
    ----------
    n : int
        Number of points, factored as ``n = nx * ny`` with ny the largest
        divisor <= sqrt(n) (a square grid for perfect squares; a prime n
        degenerates to a 1 x n grid, i.e. plain N-rooks).
    correlated : bool
        False (default): Chiu, Shirley and Wang's original, an independent
        substratum permutation per column and per row. True: Kensler's
        correlated multi-jitter, one permutation shared by all columns and
        one by all rows. Which is better depends on the integrand (measured
        below): the default is the one that is never worse than
        :func:`jittered`.

    Notes
    -----
    Point (i, j) of column i and row j has
    ``x = (i ny + p_i(j) + u) / n`` and ``y = (j nx + q_j(i) + v) / n``:
    each coarse cell holds one point (jittered) and each of the n fine
    columns and rows holds one point (rooks condition), whatever the
    permutations p, q are (lecture, slide "Multi-Jittered Sampling").
    The correlated variant is Kensler's construction (his listing's
    ``permute(row, ny)`` offsets x, ``permute(column, nx)`` offsets y, with
    a fresh jitter per sample): ``p_i = p`` and ``q_j = q`` for all i, j.

    Variance of the mean of ``exp(xy)`` over 400 replicates (seed
    20261201; ``tests/test_samplers.py`` checks the ordering by F-tests):

    ======  ==========  ==============  ================
    n       jittered    uncorrelated    correlated
    ======  ==========  ==============  ================
    256     2.0e-6      6.9e-7          1.0e-5
    1024    1.4e-7      4.9e-8          1.2e-6
    4096    9.1e-9      2.5e-9          1.6e-7
    ======  ==========  ==============  ================

    On a smooth integrand the correlated variant is *worse than plain
    jittering*, and its variance decays like n^-1.5 instead of n^-2: with
    one shared permutation the y offset ``q(i)`` of a whole column is tied
    to the column's x position ``i / nx``, so ``sum_i i q(i)`` enters the
    estimate of any integrand with a mixed derivative ``f_xy`` and its
    variance dominates (independent permutations per row average it out).
    For ``f = xy`` and ``n = m^2`` the variance of the correlated estimate
    is exactly ``(2 m^4 V1 + VZ) / n^6 ~ n^-1.5 / 72``, with
    ``V1 = m^2 (m - 1) (m + 1)^2 / 144`` the variance of ``sum_i i q(i)``
    over random permutations (once for x, once for y) and
    ``VZ = (n - 1) n (2n - 1) / 36 + 7n / 144 + n (n - 1) / 12`` from the
    jitter; measured over 4000 replicates it agrees within 2.2 % (one
    standard error) at n = 16 ... 4096, which also checks that this is
    Kensler's construction and nothing else. On the indicator of a disk
    (radius 0.4, an edge) it is the better one: variance 6.6e-6
    (correlated) vs 1.4e-5 (uncorrelated and jittered) at n = 1024 over 100
    replicates, and a lower mean star discrepancy (0.018 vs 0.021 at
    n = 256, 20 sets). Both variants have the same mean L2 star discrepancy
    (0.0040 at n = 256, 0.0014 at n = 1024; jittered 0.0063 and 0.0023).

    References
    ----------
    K. Chiu, P. Shirley and C. Wang, "Multi-jittered sampling", Graphics
    Gems IV, 1994.
    A. Kensler, "Correlated multi-jittered sampling", Pixar Technical Memo
    13-01, 2013.
    """
    correlated = check_bool(correlated, "correlated")
    if not isinstance(correlated, (bool, np.bool_)):
        raise TypeError(f"correlated must be a bool; got {type(correlated).__name__}")
    n = _count(n, 2, "multi_jittered")
    return _multi_jittered_sets(1, n, as_rng(rng), bool(correlated))[0] if n else _empty(2)


# --------------------------------------------------------------------------
# Per-pixel sample sets for the tracer
# --------------------------------------------------------------------------

def _shuffle(sets: np.ndarray, rng) -> np.ndarray:
    """Permute the points of each set (axis 1) independently."""
    count, size = sets.shape[:2]
    order = rng.permuted(np.broadcast_to(np.arange(size), (count, size)), axis=-1)
    order += np.arange(count)[:, None] * size  # flat row index: faster than take_along_axis
    return sets.reshape(count * size, -1)[order.ravel()].reshape(sets.shape)


def _xor_pixel_sets(base: np.ndarray, n_pixels: int, rng) -> np.ndarray:
    """``base`` (spp, 2) XOR-ed with a random digital shift per pixel: keeps (0, m, 2)-nets."""
    shifts = rng.integers(0, 2 ** _FRACTION_BITS, size=(n_pixels, 1, 2), dtype=np.uint64)
    return _xor_shift(base[None], shifts)


def _toroidal_pixel_sets(base: np.ndarray, n_pixels: int, rng) -> np.ndarray:
    """``base`` (spp, 2) with a random Cranley-Patterson shift per pixel."""
    return _below_one(np.mod(base[None] + rng.random((n_pixels, 1, 2)), 1.0))


def _random_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _random_sets(n_pixels, spp, 2, rng)


def _latin_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _latin_sets(n_pixels, spp, 2, rng)


def _jittered_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _shuffle(_jittered_sets(n_pixels, spp, 2, rng), rng)  # stratum order -> random order per pixel


def _multi_jittered_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _shuffle(_multi_jittered_sets(n_pixels, spp, rng, False), rng)


def _sobol_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _xor_pixel_sets(_sobol_points(spp, 2, False, None), n_pixels, rng)


def _hammersley_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _xor_pixel_sets(hammersley(spp), n_pixels, rng)


def _grid_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _toroidal_pixel_sets(_grid_base(spp, 2), n_pixels, rng)


def _halton_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    return _toroidal_pixel_sets(halton(spp), n_pixels, rng)


def _blue_noise_pixels(n_pixels: int, spp: int, rng) -> np.ndarray:
    base = _poisson_disk(spp, rng, 0.7)
    flip = rng.integers(0, 2, size=(n_pixels, 1, 3)).astype(bool)  # 8 symmetries of the square
    swapped = np.where(flip[..., 2:], base[None, :, ::-1], base[None])
    reflected = np.where(flip[..., :2], 1.0 - swapped, swapped)
    return _below_one(np.mod(reflected + rng.random((n_pixels, 1, 2)), 1.0))


def shifted_pixel_sets(sampler: Callable, n_pixels: int, spp: int, rng) -> np.ndarray:
    """Per-pixel sets of any sampler: one base set ``sampler(spp, rng=rng)``, a random
    Cranley-Patterson shift per pixel, shape ``(n_pixels, spp, 2)``.

    The default ``pixel_sets`` of a :class:`Sampler`: every pixel's set is
    uniform (a toroidal shift of anything is), the base set's structure is
    kept modulo 1, and pixels are independent given the base set.
    """
    base = np.asarray(sampler(spp, rng=rng), dtype=np.float64)
    if base.shape != (spp, 2):
        raise ValueError(f"a sampler must return shape ({spp}, 2) for n={spp}; got {base.shape}")
    return _toroidal_pixel_sets(base, n_pixels, rng)


def _pixel_pairs(name: str, n_pixels: int, spp: int, rng) -> np.ndarray:
    """One independently randomized 2D pattern per pixel: (n_pixels, spp, 2)."""
    record = SAMPLERS[name]
    if record.pixel_sets is None:
        return shifted_pixel_sets(record.function, n_pixels, spp, rng)
    return record.pixel_sets(n_pixels, spp, rng)


def pixel_samples(name: str, n_pixels, spp, *, dim: int = 2, rng=None) -> np.ndarray:
    """Sample sets for every pixel: ``(n_pixels, spp, dim)`` in [0, 1).

    Parameters
    ----------
    name : str
        A key of :data:`SAMPLERS`.
    n_pixels : int
        Number of pixels (independent sets), >= 1.
    spp : int
        Samples per pixel, >= 1: a perfect square for ``grid`` and
        ``jittered``. Unlike the samplers (where ``n = 0`` gives an empty
        set), 0 is refused here: a pixel without samples has no estimate,
        and an image without pixels is a caller's bug. ``n_pixels * spp *
        dim`` is checked against :data:`MAX_BYTES`.
    dim : int
        Dimensions per sample (2 for the pixel position, 2 more per bounce...).
    rng : None, int, SeedSequence or Generator
        The same rng gives the same array.

    Returns
    -------
    ndarray, shape (n_pixels, spp, dim), float64 in [0, 1)

    Notes
    -----
    Dimensions come in 2D pairs (0, 1), (2, 3), ...; an odd last dimension is
    the first coordinate of one more pair. Each pair is an independently
    randomized pattern per pixel, and pairs after the first are shuffled over
    the spp index independently per pixel ("padded" 2D samples, pbrt-v4's
    ``PaddedSobolSampler``): every pair is stratified, pairs are decorrelated.
    The first pair keeps the sampler's order (so the first 2^k Sobol points
    of a pixel are a net), except that jittered and multi-jittered sets are
    put in random order: then every sample index, not only the whole set, is
    uniform over the pixel, and any prefix of the spp samples is unbiased.

    Randomization per pixel, vectorised (no loop over pixels):

    ======================================  ==========================================
    sampler                                 per-pixel set
    ======================================  ==========================================
    random, jittered, n_rooks,              drawn independently for each pixel
    multi_jittered (uncorrelated)
    sobol, hammersley                       one deterministic base set (unscrambled
                                            Sobol', Hammersley) XOR-ed with a random
                                            digital shift per pixel: keeps the
                                            (0, m, 2)-net for spp = 2^m, pixels fully
                                            independent, costs one XOR per sample
    grid, halton                            the deterministic base set with a random
                                            Cranley-Patterson shift per pixel (grid
                                            stays one point per cell)
    blue_noise                              one toroidal Poisson-disk base set drawn
                                            from ``rng``, per pixel a random symmetry
                                            of the square and a toroidal shift (the
                                            Poisson-disk radius is kept; pixels share
                                            the base set, so they are independent only
                                            given it)
    ======================================  ==========================================

    Examples
    --------
    >>> pixel_samples("sobol", 4, 16, dim=4, rng=3).shape
    (4, 16, 4)
    """
    name = check_choice(name, "name", SAMPLERS)
    n_pixels = check_count(n_pixels, "n_pixels")
    spp = check_count(spp, "spp")
    d = _check_dim(dim)
    if SAMPLERS[name].square:
        _integer_root(spp, 2, name, "spp")  # clear error before any work
    _check_memory(spp, max(d, 2), "pixel_samples", what="spp", sets=n_pixels)
    if name == "sobol" and SAMPLERS[name].pixel_sets is _sobol_pixels:
        # the same draws, written as rows (no per-pair float/uint64 round trips, no
        # gather of interleaved pairs), then laid out (n_pixels, spp, d) in one copy
        cols = pixel_sample_columns(name, n_pixels, spp, dim=d, rng=rng)
        return np.ascontiguousarray(cols.reshape(d, n_pixels, spp).transpose(1, 2, 0))
    return _pixel_samples_by_pairs(name, n_pixels, spp, d, rng)


def _pixel_samples_by_pairs(name: str, n_pixels: int, spp: int, d: int, rng) -> np.ndarray:
    """:func:`pixel_samples` pair by pair (every sampler; sobol's rows in
    :func:`pixel_sample_columns` give the same values faster)."""
    pairs = (d + 1) // 2
    streams = as_rng(rng).spawn(pairs)
    out = np.empty((n_pixels, spp, 2 * pairs))
    for k, gen in enumerate(streams):
        block = _pixel_pairs(name, n_pixels, spp, gen)
        if k:
            block = _shuffle(block, gen)
        out[:, :, 2 * k:2 * k + 2] = block
    return out[:, :, :d]


def pixel_sample_columns(name: str, n_pixels, spp, *, dim: int = 2, rng=None) -> np.ndarray:
    """:func:`pixel_samples` as columns: ``(dim, n_pixels * spp)``, the same values.

    ``out[j, p * spp + i] == pixel_samples(...)[p, i, j]`` for the same
    ``rng``: the layout a wavefront tracer reads (a dimension is one
    contiguous row), without the interleaved ``(..., dim)`` array and its
    transposes. For ``sobol`` the XOR shift and the padding shuffle are
    written straight into the rows (the same draws in the same order);
    other samplers are transposed from :func:`pixel_samples`.
    """
    name = check_choice(name, "name", SAMPLERS)
    if name != "sobol" or SAMPLERS[name].pixel_sets is not _sobol_pixels:
        return np.ascontiguousarray(pixel_samples(name, n_pixels, spp, dim=dim, rng=rng).reshape(-1, dim).T)
    n_pixels = check_count(n_pixels, "n_pixels")
    spp = check_count(spp, "spp")
    d = _check_dim(dim)
    _check_memory(spp, max(d, 2), "pixel_samples", what="spp", sets=n_pixels)
    pairs = (d + 1) // 2
    streams = as_rng(rng).spawn(pairs)
    bits = np.ldexp(_sobol_points(spp, 2, False, None), _FRACTION_BITS).astype(np.uint64)   # (spp, 2)
    out = np.empty((2 * pairs, n_pixels * spp))
    scale = 2.0 ** -_FRACTION_BITS
    for k, gen in enumerate(streams):
        shifts = gen.integers(0, 2 ** _FRACTION_BITS, size=(n_pixels, 1, 2), dtype=np.uint64)
        order = None
        if k:        # _shuffle's permutation, drawn after the shifts as there
            order = gen.permuted(np.broadcast_to(np.arange(spp), (n_pixels, spp)), axis=-1)
            order += np.arange(n_pixels)[:, None] * spp
            order = order.ravel()
        for c in range(2):
            col = (bits[None, :, c] ^ shifts[:, :, c]).reshape(-1)
            if order is not None:
                col = col[order]
            row = out[2 * k + c]
            row[...] = col
            row *= scale
    return out[:d]


# --------------------------------------------------------------------------
# The registry: one record per sampler
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Sampler:
    """Everything mcvar needs to know about one sampler; called like its function.

    Attributes
    ----------
    name : str
        The key in :data:`SAMPLERS` (``--sampler NAME``, ``render(sampler=NAME)``).
    function : callable
        ``function(n, *, rng=None, **options) -> (n, 2)`` in [0, 1).
    star_slope : float
        Expected log-log slope of the star discrepancy against n (the
        samplers report draws it beside the fitted one).
    star_slope_why : str
        Where that slope comes from (one line, shown in ``slopes.csv``).
    square : bool
        True: n must be a perfect square (``grid``, ``jittered``); callers
        that choose n (the samplers report, the renderer's batch sizes) pick
        squares.
    deterministic : bool
        True: the default options ignore ``rng`` (the same points each call).
    iid : bool
        True: the points are independent, so one set's iid standard error is
        right (the estimators need no replicates); False for stratified and
        QMC points, whose samples are dependent.
    words_per_coord : int
        Peak working memory in 8-byte words per output coordinate (checked
        against :data:`MAX_BYTES` before allocating).
    pixel_sets : callable or None
        ``pixel_sets(n_pixels, spp, rng) -> (n_pixels, spp, 2)``: one
        independently randomized pattern per pixel, vectorised over pixels
        (:func:`pixel_samples`). None: :func:`shifted_pixel_sets` (one base
        set, a Cranley-Patterson shift per pixel).

    Examples
    --------
    >>> SAMPLERS["jittered"].square, SAMPLERS["random"].iid
    (True, True)
    >>> SAMPLERS["sobol"](4, rng=1).shape
    (4, 2)
    """

    name: str
    function: Callable
    star_slope: float
    star_slope_why: str = ""
    square: bool = False
    deterministic: bool = False
    iid: bool = False
    words_per_coord: int = 4
    pixel_sets: Callable | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"Sampler.name must be an identifier-like string; got {self.name!r}")
        for key in ("function", "pixel_sets"):
            value = getattr(self, key)
            if not callable(value) and not (key == "pixel_sets" and value is None):
                raise TypeError(f"Sampler.{key} must be callable; got {type(value).__name__}")
        slope = self.star_slope
        if isinstance(slope, bool) or not isinstance(slope, (int, float)) or not -2.0 <= slope < 0.0:
            raise ValueError(f"Sampler.star_slope must be a number in [-2, 0); got {slope!r}")
        words = self.words_per_coord
        if isinstance(words, bool) or not isinstance(words, int) or words < 1:
            raise ValueError(f"Sampler.words_per_coord must be an int >= 1; got {words!r}")

    def __call__(self, n, **options):
        return self.function(n, **options)


#: The samplers by name: :class:`Sampler` records (the tracer, the estimators and
#: the reports look them up here). Memory: tracemalloc peaks at n = 2^16 (blue
#: noise 2^14), rounded up with a margin (measured: random 1.0, grid 2.1,
#: jittered 3.1, n_rooks 3.0, multi_jittered 1.6, hammersley/halton 3.6, sobol
#: 9.1 (scipy), blue_noise 24). Star-discrepancy slopes: for the nets the log
#: factors make the slope fitted on n = 64 ... 4096 read about -1 + a / ln n
#: (-0.85 for log n / n, -0.7 for log^2 n / n).
SAMPLERS: dict[str, Sampler] = {}


def register_sampler(sampler: Sampler) -> Sampler:
    """Add ``sampler`` to :data:`SAMPLERS` (a duplicate name is a ``ValueError``); return it.

    See docs/samplers.md, 'Adding a sampler'.
    """
    if not isinstance(sampler, Sampler):
        raise TypeError(f"register_sampler takes a Sampler; got {type(sampler).__name__}")
    if sampler.name in SAMPLERS:
        raise ValueError(f"a sampler named {sampler.name!r} is already registered")
    SAMPLERS[sampler.name] = sampler
    return sampler


for _record in (
    Sampler("random", random, -0.5, "E D* ~ c n^-1/2 (sqrt(n) D* has a limit law)", iid=True,
            words_per_coord=2, pixel_sets=_random_pixels),
    Sampler("grid", grid, -0.5, "a row of sqrt(n) points enters a box at once", square=True,
            deterministic=True, words_per_coord=3, pixel_sets=_grid_pixels),
    Sampler("jittered", jittered, -0.75, "E D* <= C n^-3/4 sqrt(log n) (Pausinger & Steinerberger 2016)",
            square=True, pixel_sets=_jittered_pixels),
    Sampler("n_rooks", n_rooks, -0.5, "like random for 2D boxes (Doerr, Doerr & Gnewuch 2018)",
            pixel_sets=_latin_pixels),
    Sampler("multi_jittered", multi_jittered, -0.75, "jittered, so at least n^-3/4", words_per_coord=3,
            pixel_sets=_multi_jittered_pixels),
    Sampler("hammersley", hammersley, -1.0, "O(log n / n) for n = 2^m: a (0, m, 2)-net", deterministic=True,
            pixel_sets=_hammersley_pixels),
    Sampler("halton", halton, -1.0, "O(log^2 n / n)", deterministic=True, pixel_sets=_halton_pixels),
    Sampler("sobol", sobol, -1.0, "O(log n / n): (0, m, 2)-nets", words_per_coord=10, pixel_sets=_sobol_pixels),
    Sampler("blue_noise", blue_noise, -0.5, "dart throwing is not hyperuniform: P(k -> 0) ~ 0.1 > 0, so box "
            "counts fluctuate like random ones, ~0.3x smaller; -0.5 asymptotically", words_per_coord=32,
            pixel_sets=_blue_noise_pixels),
):
    register_sampler(_record)
del _record

#: The built-in samplers whose default options ignore ``rng``: the same points every call
#: (``SAMPLERS[name].deterministic`` for any registered one). Independent, unbiased
#: replicates of them need a randomization such as :func:`digital_shift` (which keeps
#: (0, m, 2)-nets nets).
DETERMINISTIC = frozenset(name for name, rec in SAMPLERS.items() if rec.deterministic)


def sampler_record(name: str) -> Sampler:
    """The :class:`Sampler` record called ``name``; ValueError listing the valid names otherwise."""
    return SAMPLERS[check_choice(name, "sampler name", SAMPLERS)]


def get_sampler(name: str):
    """The sampler function called ``name``; ValueError listing the valid names otherwise."""
    return sampler_record(name).function

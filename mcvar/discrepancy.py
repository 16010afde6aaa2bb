"""Discrepancy and power spectra of point sets (layer 2).

The lecture's slide "Low-Discrepancy Sampling" defines the local discrepancy of
a point set X in a region S, ``d_S(X) = |A(S) - n(S) / |X||``, and the
discrepancy ``D(X) = sup_{S in F} d_S(X)`` over a family F of regions. This
module computes

* :func:`star`: F = anchored boxes [0, x) x [0, y), exactly;
* :func:`l2_star` (Warnock's closed form), :func:`centered`,
  :func:`wrap_around`, :func:`mixture`: the L2 discrepancies (root mean square
  of a local discrepancy instead of its sup), each returning the discrepancy
  itself unless ``squared=True`` (the table in ``docs/discrepancy.md`` lists
  what scipy returns for comparison);
* :func:`local`: the sup over anchored boxes, arbitrary axis-aligned boxes or
  disks on a documented dense set of regions, with the region that attains it;
* :func:`is_net`: the (t, m, 2)-net property of Sobol and Hammersley points;
* :func:`power_spectrum`: the periodogram with its radial average and an
  anisotropy measure (lecture, slides "Blue Noise Fourier Transform").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.stats import qmc

from ._validation import as_points, check_bool, check_choice, check_count

__all__ = [
    "star",
    "l2_star",
    "centered",
    "wrap_around",
    "mixture",
    "DISCREPANCIES",
    "is_net",
    "LocalDiscrepancy",
    "local",
    "PowerSpectrum",
    "power_spectrum",
]

_BLOCK = 512  # rows per block in the O(n^2) loops: bounds memory to ~_BLOCK * n floats


def _unit_points(points, *, d=None) -> np.ndarray:
    pts = as_points(points, "points", d=d, unit=True)
    if pts.shape[0] == 0:
        raise ValueError("points must hold at least one point; got shape "
                         f"{pts.shape}")
    return pts


# --------------------------------------------------------------------------
# Star discrepancy (exact, 2D)
# --------------------------------------------------------------------------

def star(points) -> float:
    """The exact star discrepancy of a 2D point set.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Points in [0, 1]^2 (ties allowed).

    Returns
    -------
    float
        ``D*(X) = sup_{x, y in [0, 1]} |x y - #{p in [0, x) x [0, y)} / n|``.

    Notes
    -----
    The supremum is attained on the *critical grid* Gx x Gy, where Gx (Gy)
    holds the points' x (y) coordinates and 1 (Niederreiter 1972): with
    ``C(a, b)`` the number of points in the closed box [0, a] x [0, b] and
    ``O(a, b)`` the number in the open box [0, a) x [0, b),

    ``D* = max_{a in Gx, b in Gy} max(C(a, b) / n - a b, a b - O(a, b) / n)``.

    Both counts come from one 2D cumulative sum of the points' rank
    histogram, processed in blocks of rows: O(n^2) time, O(n) memory per
    block row; n = 4096 takes a fraction of a second. This is the lecture's
    D(X) for the family of anchored boxes.

    References
    ----------
    H. Niederreiter, "Discrepancy and convex programming", Ann. Mat. Pura
    Appl. 93, 1972.
    D. P. Dobkin, D. Eppstein and D. P. Mitchell, "Computing the discrepancy
    with applications to supersampling patterns", ACM TOG 15(4), 1996.

    Examples
    --------
    >>> star([[0.5, 0.5]])  # max(1 - x y, x, y) for a single point
    0.75
    """
    pts = _unit_points(points, d=2)
    n = pts.shape[0]
    gx = np.union1d(pts[:, 0], [1.0])
    gy = np.union1d(pts[:, 1], [1.0])
    ix = np.searchsorted(gx, pts[:, 0])
    iy = np.searchsorted(gy, pts[:, 1])
    order = np.argsort(ix, kind="stable")
    ix, iy = ix[order], iy[order]
    starts = np.searchsorted(ix, np.arange(0, gx.size + _BLOCK, _BLOCK))
    carry = np.zeros(gy.size, dtype=np.int64)  # C(gx[a0 - 1], .)
    best = 0.0
    for block, a0 in enumerate(range(0, gx.size, _BLOCK)):
        a1 = min(a0 + _BLOCK, gx.size)
        lo, hi = starts[block], starts[block + 1]
        hist = np.zeros((a1 - a0) * gy.size, dtype=np.int64)
        np.add.at(hist, (ix[lo:hi] - a0) * gy.size + iy[lo:hi], 1)
        closed = carry + np.cumsum(np.cumsum(hist.reshape(a1 - a0, gy.size), axis=1), axis=0)
        previous = np.vstack([carry[None], closed[:-1]])  # C(gx[a - 1], .)
        opened = np.zeros_like(previous)
        opened[:, 1:] = previous[:, :-1]  # O(gx[a], gy[b]) = C(gx[a - 1], gy[b - 1])
        volume = gx[a0:a1, None] * gy[None, :]
        best = max(best, float(np.max(closed / n - volume)), float(np.max(volume - opened / n)))
        carry = closed[-1]
    return best


# --------------------------------------------------------------------------
# L2 discrepancies
# --------------------------------------------------------------------------

def l2_star(points, *, squared: bool = False) -> float:
    """The L2-star discrepancy (Warnock's closed form), or its square.

    Parameters
    ----------
    points : array_like, shape (n, d)
        Points in [0, 1]^d.
    squared : bool
        Return ``T^2`` instead of ``T``.

    Notes
    -----
    ``T`` is the root mean square of the local discrepancy of anchored boxes,
    ``T^2 = int_[0,1]^d (vol[0, x) - #{p in [0, x)} / n)^2 dx``, which
    Warnock's formula evaluates exactly:

    ``T^2 = 3^-d - 2^(1-d) / n sum_i prod_k (1 - x_ik^2)
    + 1 / n^2 sum_i sum_j prod_k (1 - max(x_ik, x_jk))``.

    Evaluated by ``scipy.stats.qmc.discrepancy(points, method="L2-star")``
    (compiled, O(n^2 d)), which returns T, the root, whereas scipy's "CD",
    "WD" and "MD" return squares; the tests check it against a direct NumPy
    evaluation of the formula above.

    References
    ----------
    T. T. Warnock, "Computational investigations of low-discrepancy point
    sets", in Applications of Number Theory to Numerical Analysis, 1972.
    """
    pts = _unit_points(points)
    sq = check_bool(squared, "squared")
    value = float(qmc.discrepancy(pts, method="L2-star"))  # scipy returns T, the root
    return value ** 2 if sq else value


def _scipy_squared(points, method: str, squared) -> float:
    pts = _unit_points(points)
    sq = check_bool(squared, "squared")
    value = max(float(qmc.discrepancy(pts, method=method)), 0.0)  # scipy returns the square
    return value if sq else math.sqrt(value)


def centered(points, *, squared: bool = False) -> float:
    """Hickernell's centered L2 discrepancy (CD), or its square.

    Notes
    -----
    Boxes anchored at the nearest corner of each coordinate's centre instead
    of the origin, so the measure is invariant under reflections
    ``x_k -> 1 - x_k``:

    ``CD^2 = (13/12)^d - 2/n sum_i prod_k (1 + |x_ik - 1/2|/2 - |x_ik - 1/2|^2/2)
    + 1/n^2 sum_ij prod_k (1 + |x_ik - 1/2|/2 + |x_jk - 1/2|/2 - |x_ik - x_jk|/2)``.

    Calls ``scipy.stats.qmc.discrepancy(method="CD")``, which returns CD^2.

    References
    ----------
    F. J. Hickernell, "A generalized discrepancy and quadrature error bound",
    Math. Comp. 67(221), 1998.
    """
    return _scipy_squared(points, "CD", squared)


def wrap_around(points, *, squared: bool = False) -> float:
    """Hickernell's wrap-around L2 discrepancy (WD), or its square.

    Notes
    -----
    Boxes on the torus (wrapping at 1), so the measure is invariant under
    Cranley-Patterson shifts:

    ``WD^2 = -(4/3)^d + 1/n^2 sum_ij prod_k (3/2 - |x_ik - x_jk| (1 - |x_ik - x_jk|))``.

    Calls ``scipy.stats.qmc.discrepancy(method="WD")``, which returns WD^2.

    References
    ----------
    F. J. Hickernell, "Lattice rules: how well do they measure up?", in
    Random and Quasi-Random Point Sets, Springer, 1998.
    """
    return _scipy_squared(points, "WD", squared)


def mixture(points, *, squared: bool = False) -> float:
    """Zhou, Fang and Ning's mixture L2 discrepancy (MD), or its square.

    Notes
    -----
    Mixes the centered and wrap-around constructions; Zhou et al. argue it
    avoids the blind spots of both. Calls
    ``scipy.stats.qmc.discrepancy(method="MD")``, which returns MD^2.

    References
    ----------
    Y.-D. Zhou, K.-T. Fang and J.-H. Ning, "Mixture discrepancy for
    quasi-random point sets", J. Complexity 29(3-4), 2013.
    """
    return _scipy_squared(points, "MD", squared)


#: Every global discrepancy by name; each returns the discrepancy (not squared).
DISCREPANCIES = {
    "star": star,
    "l2_star": l2_star,
    "centered": centered,
    "wrap_around": wrap_around,
    "mixture": mixture,
}


# --------------------------------------------------------------------------
# Nets
# --------------------------------------------------------------------------

def is_net(points, m: int, base: int = 2, *, t: int = 0) -> bool:
    """Whether ``base**m`` points form a (t, m, 2)-net in ``base``.

    Parameters
    ----------
    points : array_like, shape (base**m, 2)
        Points in [0, 1)^2.
    m : int
        ``log_base`` of the number of points (m >= 0).
    base : int
        The base b >= 2.
    t : int
        Quality parameter, 0 <= t <= m (t = 0 is the strongest net).

    Returns
    -------
    bool
        True if every elementary interval
        ``[a / b^k, (a + 1) / b^k) x [c / b^(m-t-k), (c + 1) / b^(m-t-k))``,
        k = 0 ... m - t, of area b^(t-m) holds exactly b^t points.

    Notes
    -----
    A (0, m, 2)-net is stratified simultaneously on every grid of b^m cells
    of the same shape (1 x b^m, b x b^(m-1), ..., b^m x 1): jittered and
    N-rooks at once, and more. Sobol (every aligned block of 2^m points) and
    Hammersley points with n = 2^m are (0, m, 2)-nets in base 2, hence star
    discrepancy O(log n / n).

    Points of nets sit on cell boundaries a / b^k, which are exact in binary
    floating point only for b = 2 (``radical_inverse(1, 3)`` is 1/3 rounded
    down); a coordinate within a relative 1e-12 below a boundary is counted
    in the cell above it.

    References
    ----------
    H. Niederreiter, "Random Number Generation and Quasi-Monte Carlo
    Methods", SIAM, 1992, chapter 4.

    Examples
    --------
    >>> is_net([[0.0, 0.0], [0.5, 0.5], [0.25, 0.75], [0.75, 0.25]], m=2)
    True
    """
    m = check_count(m, "m", allow_zero=True)
    b = check_count(base, "base")
    if b < 2:
        raise ValueError(f"base must be >= 2; got {b}")
    t = check_count(t, "t", allow_zero=True)
    if t > m:
        raise ValueError(f"t must be <= m = {m}; got {t}")
    pts = as_points(points, "points", d=2)
    if pts.shape[0] != b ** m:
        raise ValueError(f"points must hold base**m = {b ** m} points for a (t, {m}, 2)-net; "
                         f"got {pts.shape[0]}")
    if not (np.all(pts >= 0.0) and np.all(pts < 1.0)):
        raise ValueError("points must lie in [0, 1)^2 (an elementary interval is half-open)")
    cells = b ** (m - t)

    def cell(x, scale):  # see Notes: boundaries a / b^k in floating point
        return np.minimum(np.floor(x * scale * (1.0 + 1e-12)), scale - 1).astype(np.int64)

    for k in range(m - t + 1):
        cx = cell(pts[:, 0], b ** k)
        cy = cell(pts[:, 1], b ** (m - t - k))
        counts = np.bincount(cx * b ** (m - t - k) + cy, minlength=cells)
        if counts.size != cells or not np.all(counts == b ** t):
            return False
    return True


# --------------------------------------------------------------------------
# Local discrepancy over families of regions
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class LocalDiscrepancy:
    """The sup of the local discrepancy over a family of regions.

    Attributes
    ----------
    value : float
        ``max d_S(X)`` over the regions evaluated (exact for each of them).
    upper : float
        An upper bound of the sup over the *whole* family (``value`` plus the
        discretisation bound; equal to ``value`` when none is known).
    region : tuple of float
        The region attaining ``value``: ``(x0, y0, x1, y1)`` for boxes,
        ``(cx, cy, r)`` for disks.
    family : str
        ``"anchored"``, ``"boxes"`` or ``"disks"``.
    n_regions : int
        Number of regions evaluated (for disks: centres x candidate radii).
    """

    value: float
    upper: float
    region: tuple
    family: str
    n_regions: int


def _box_sup(pts: np.ndarray, r: int, anchored: bool):
    n = pts.shape[0]
    cell = np.minimum(np.floor(pts * r).astype(np.int64), r - 1)
    hist = np.zeros((r, r), dtype=np.int64)
    np.add.at(hist, (cell[:, 0], cell[:, 1]), 1)
    sat = np.zeros((r + 1, r + 1), dtype=np.int64)  # sat[i, j]: points in [0, i/r) x [0, j/r)
    sat[1:, 1:] = np.cumsum(np.cumsum(hist, axis=0), axis=1)
    edges = np.arange(r + 1) / r
    if anchored:
        dev = np.abs(edges[:, None] * edges[None, :] - sat / n)
        i, j = np.unravel_index(np.argmax(dev), dev.shape)
        return float(dev[i, j]), (0.0, 0.0, float(edges[i]), float(edges[j])), (r + 1) ** 2
    best, region = -1.0, None
    widths = edges[None, :] - edges[:, None]  # x1 - x0 for x0 index i, x1 index j
    for i0 in range(r):  # lower x edge; the rest vectorised over (x1, y0, y1)
        strip = sat[i0 + 1:, :] - sat[i0, :]  # points in [x0, x1) x [0, y)
        counts = strip[:, None, :] - strip[:, :, None]  # (x1, y0, y1)
        area = widths[i0, i0 + 1:, None, None] * widths[None, :, :]
        dev = np.abs(area - counts / n)
        dev[:, widths <= 0] = 0.0
        k = int(np.argmax(dev))
        if dev.flat[k] > best:
            a, b0, b1 = np.unravel_index(k, dev.shape)
            best = float(dev.flat[k])
            region = (float(edges[i0]), float(edges[b0]), float(edges[i0 + 1 + a]), float(edges[b1]))
    return best, region, (r * (r + 1) // 2) ** 2


def _disk_sup(pts: np.ndarray, r: int):
    n = pts.shape[0]
    centres = (np.stack(np.meshgrid(np.arange(r), np.arange(r), indexing="ij"), -1).reshape(-1, 2)
               + 0.5) / r
    rmax = np.min(np.minimum(centres, 1.0 - centres), axis=1)  # disks inside the square
    best, region = -1.0, None
    for c0 in range(0, centres.shape[0], 64):
        c = centres[c0:c0 + 64]
        dist = np.sort(np.sqrt(np.sum((pts[None] - c[:, None]) ** 2, axis=-1)), axis=1)
        k = np.arange(1, n + 1)
        radius_cap = rmax[c0:c0 + 64, None]
        inside = dist <= radius_cap
        area = np.pi * dist ** 2
        # at radius d_(k): the closed disk holds k points, the open one k - 1
        over = np.where(inside, k / n - area, -np.inf)
        under = np.where(inside, area - (k - 1) / n, -np.inf)
        # at the largest radius: the closed disk holds every point with d <= rmax
        at_cap = np.sum(inside, axis=1)
        cap_area = np.pi * radius_cap[:, 0] ** 2
        cap_dev = np.abs(cap_area - at_cap / n)
        dev = np.maximum(np.max(np.maximum(over, under), axis=1), cap_dev)
        arg_c = int(np.argmax(dev))
        if dev[arg_c] > best:
            best = float(dev[arg_c])
            row = np.maximum(over[arg_c], under[arg_c])
            kk = int(np.argmax(row))
            rad = float(dist[arg_c, kk]) if row[kk] >= cap_dev[arg_c] else float(radius_cap[arg_c, 0])
            region = (float(c[arg_c, 0]), float(c[arg_c, 1]), rad)
    return best, region, centres.shape[0] * (n + 1)


def local(points, family: Literal["anchored", "boxes", "disks"] = "anchored", *,
          resolution: int = 32) -> LocalDiscrepancy:
    """The lecture's ``D(X) = sup_{S in F} |A(S) - n(S) / |X|||`` for a family F.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Points in [0, 1]^2.
    family : {"anchored", "boxes", "disks"}
        ``"anchored"``: boxes [0, x) x [0, y); ``"boxes"``: every axis-aligned
        box [x0, x1) x [y0, y1); ``"disks"``: disks inside the unit square.
    resolution : int
        The grid step 1 / resolution of the evaluated regions (see Notes).

    Returns
    -------
    LocalDiscrepancy
        The largest local discrepancy found, an upper bound for the family,
        and the region attaining it.

    Notes
    -----
    Lecture slide "Low-Discrepancy Sampling". Regions evaluated, each exactly:

    * anchored: corners (x, y) on the grid {0, 1/r, ..., 1}^2. Every anchored
      box lies between two grid boxes whose areas differ by <= 2/r, so the
      sup over all anchored boxes (the star discrepancy, computed exactly by
      :func:`star`) lies in [value, value + 2/r] (``upper``).
    * boxes: all (r (r + 1) / 2)^2 grid boxes [i/r, j/r) x [k/r, l/r); by the
      same sandwich, the sup over all boxes (the extreme discrepancy) lies in
      [value, value + 4/r]. Cost O(r^4) (resolution 32: 0.3 M boxes).
    * disks: centres on the r x r grid of cell centres and, for each centre,
      *every* radius up to the distance to the square's border: the
      discrepancy of a disk jumps only at the points' distances, so the sup
      over radii is exact (open and closed disks). ``upper`` is ``value``
      (no bound is claimed for centres off the grid).

    Examples
    --------
    >>> res = local([[0.5, 0.5]], "anchored", resolution=2)
    >>> res.value, res.upper, res.region  # star([[0.5, 0.5]]) = 0.75 lies in between
    (0.5, 1.5, (0.0, 0.0, 0.5, 1.0))
    """
    pts = _unit_points(points, d=2)
    family = check_choice(family, "family", ("anchored", "boxes", "disks"))
    r = check_count(resolution, "resolution")
    if family == "disks":
        value, region, count = _disk_sup(pts, r)
        return LocalDiscrepancy(value, value, region, family, count)
    value, region, count = _box_sup(pts, r, family == "anchored")
    slack = (2.0 if family == "anchored" else 4.0) / r
    return LocalDiscrepancy(value, value + slack, region, family, count)


# --------------------------------------------------------------------------
# Power spectrum
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class PowerSpectrum:
    """The periodogram of a point set and its radial summaries.

    Attributes
    ----------
    frequencies : ndarray, shape (2 K + 1,)
        Integer frequencies -K ... K on each axis (cycles per unit length).
    power : ndarray, shape (2 K + 1, 2 K + 1)
        ``P(k) = |sum_j exp(-2 pi i k . x_j)|^2 / n``, indexed [kx, ky]; the
        DC term P(0) = n. Uniform random points have E[P(k)] = 1 for k != 0.
    radial_frequency : ndarray, shape (K,)
        Annulus centres 1, 2, ..., K (annulus f holds f - 1/2 <= |k| < f + 1/2).
    radial_power : ndarray, shape (K,)
        Mean of P over each annulus.
    radial_anisotropy : ndarray, shape (K,)
        ``var(P) / mean(P)^2`` over each annulus (Ulichney): about 1 for an
        isotropic random spectrum, >> 1 where the power sits in spikes; 0
        for an annulus without power (mean below 1e-12 n, rounding noise).
    anisotropy : float
        Mean of ``radial_anisotropy`` over the annuli 1 ... K that hold power.
    n : int
        Number of points.
    """

    frequencies: np.ndarray
    power: np.ndarray
    radial_frequency: np.ndarray
    radial_power: np.ndarray
    radial_anisotropy: np.ndarray
    anisotropy: float
    n: int

    def low_frequency_power(self, cutoff: float) -> float:
        """Mean P(k) over 0 < |k| < cutoff (1 for random points; << 1 for blue noise)."""
        if not cutoff > 1.0:
            raise ValueError(f"cutoff must be > 1 (the lowest nonzero frequency); got {cutoff}")
        kx, ky = np.meshgrid(self.frequencies, self.frequencies, indexing="ij")
        radius = np.hypot(kx, ky)
        mask = (radius > 0) & (radius < cutoff)
        return float(np.mean(self.power[mask]))


def power_spectrum(points, *, k_max: int | None = None) -> PowerSpectrum:
    """The periodogram of a 2D point set, radially averaged, with an anisotropy measure.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Points in [0, 1]^2, seen as one period of a periodic pattern.
    k_max : int, optional
        Largest integer frequency K on each axis; default
        ``max(8, ceil(2 sqrt(n)))``, twice the mean-spacing frequency
        sqrt(n), so that a blue-noise ring lies well inside.

    Returns
    -------
    PowerSpectrum

    Notes
    -----
    The Fourier coefficients ``S(k) = sum_j exp(-2 pi i (kx x_j + ky y_j))``
    factor into ``E_x E_y^T`` with ``E_x[kx, j] = exp(-2 pi i kx x_j)``:
    one complex matrix product, O(K^2 n). Normalised by n, white noise has
    a flat spectrum of height 1; a grid has spikes at multiples of sqrt(n);
    blue noise has a dark centre (low-frequency power << 1) and a bright
    ring at the mean spacing, the same in every direction (isotropic: the
    lecture's "no preferred direction", which the slide mislabels
    "anisotropic"). Integer frequencies make the pattern's periodic
    extension the signal, so there is no window leakage.

    References
    ----------
    R. A. Ulichney, "Dithering with blue noise", Proc. IEEE 76(1), 1988.
    D. Heck, T. Schloemer and O. Deussen, "Blue noise sampling with
    controlled aliasing", ACM TOG 32(3), 2013.
    """
    pts = _unit_points(points, d=2)
    n = pts.shape[0]
    if k_max is None:
        kmax = max(8, int(math.ceil(2.0 * math.sqrt(n))))
    else:
        kmax = check_count(k_max, "k_max")
    freqs = np.arange(-kmax, kmax + 1)
    ex = np.exp(-2j * np.pi * freqs[:, None] * pts[None, :, 0])
    ey = np.exp(-2j * np.pi * freqs[:, None] * pts[None, :, 1])
    power = np.abs(ex @ ey.T) ** 2 / n
    kx, ky = np.meshgrid(freqs, freqs, indexing="ij")
    ring = np.rint(np.hypot(kx, ky)).astype(np.int64)
    valid = (ring >= 1) & (ring <= kmax)
    counts = np.bincount(ring[valid], minlength=kmax + 1)[1:]
    sums = np.bincount(ring[valid], weights=power[valid], minlength=kmax + 1)[1:]
    squares = np.bincount(ring[valid], weights=power[valid] ** 2, minlength=kmax + 1)[1:]
    mean = sums / counts
    var = squares / counts - mean ** 2
    silent = mean <= 1e-12 * n  # an annulus with only rounding noise (e.g. a grid's) has none
    with np.errstate(divide="ignore", invalid="ignore"):
        aniso = np.where(silent, 0.0, np.maximum(var, 0.0) / mean ** 2)
    overall = float(np.mean(aniso[~silent])) if np.any(~silent) else 0.0
    return PowerSpectrum(freqs, power, np.arange(1, kmax + 1, dtype=np.float64), mean, aniso,
                         overall, n)

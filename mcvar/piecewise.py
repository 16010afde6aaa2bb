"""Piecewise-constant distributions in 1D and 2D, sampled by inversion (layer 2).

The lecture's 'Creating A PDF' and 'Inversion Sampling' slides, built as
pbrt-v4's ``PiecewiseConstant1D`` and ``PiecewiseConstant2D`` (same names,
same semantics): a non-negative function tabulated on ``n`` equal cells of an
interval (or ``nv x nu`` cells of a rectangle) becomes a density proportional
to it. Each class holds its sampler and its pdf side by side:

``sample(u)``
    Inverts the CDF: returns the continuous value ``x``, its density ``pdf``
    (per unit length, or per unit area in 2D) and the cell ``offset``.
``sample_discrete(u)``
    The same inversion, returning the cell, its probability and ``u``
    remapped to [0, 1) inside the cell (pbrt-v4's ``SampleDiscrete``):
    what a caller needs that chooses a *cell*, e.g. a light.
``pdf(x)``
    The density ``sample`` produces at ``x``; exactly 0 outside the domain
    and in cells of zero mass.
``integral``
    ``integral of f`` over the domain (the normalisation).
``invert(x)``
    The ``u`` that ``sample`` maps to ``x`` (pbrt-v4's ``Invert``).

Conventions (shared with :class:`mcvar.envmap.EnvironmentMap`, which samples
its pixels with these classes):

* ``u`` lies in the closed interval [0, 1]; ``u = 1.0`` exactly selects the
  last cell of non-zero mass, never an index past the end nor a zero-mass
  cell. Cells of zero mass are never selected.
* Cell probabilities are the differences of the stored CDF
  (``pmf = diff(cdf)``), the probability each step of the inverted CDF
  really has, so ``pdf`` agrees with ``sample`` to the last bit.
* **All-zero function**: as in pbrt-v4, the CDF becomes that of the uniform
  distribution and ``sample`` draws uniformly over the domain; unlike
  pbrt-v4 (which reports ``pdf = 0`` then) the pdf returned and ``pdf(x)``
  are the uniform density actually used, ``1 / (max - min)``, and
  ``integral`` is 0. The 2D class does the same per row (a row of zeros in
  a non-zero function is never chosen).

**Light selection by power** (one-sample choice of a light with probability
proportional to its power, pbrt-v4's ``PowerLightSampler``)::

    select = PiecewiseConstant1D(powers)          # powers: (L,) >= 0
    x, pdf, light = select.sample(u)              # u: (n,) uniform in [0, 1]
    probability = select.pmf[light]               # = powers[light] / powers.sum()

(``pdf`` is per unit ``x`` on [0, 1], i.e. ``L`` times the probability;
``sample_discrete(u)`` returns ``(light, probability, u_remapped)``
directly, with ``u_remapped`` uniform again for reuse.) All lights of zero
power: a uniform choice, probability ``1 / L``.

References
----------
.. [1] M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering: From
   Theory to Implementation*, 4th ed., MIT Press, 2023, sec. A.4.7
   (``SampleDiscrete``), A.5 (piecewise-constant 1D and 2D distributions),
   12.6 (light sampling by power).
"""
from __future__ import annotations

import numbers

import numpy as np

from ._validation import as_array, as_points, as_unit_square

__all__ = ["PiecewiseConstant1D", "PiecewiseConstant2D"]

# CDFs up to this many entries are searched without sorting the values first (measured
# on 10^6 values: direct search is faster up to ~64 entries, sorting wins from ~256 on).
_SMALL_TABLE = 64
#: A cell must span more than this many floats at its domain's magnitude (so
#: that a point moved by a few ulps, :func:`_in_cell`, stays inside it).
_MIN_CELL_ULPS = 16


def _interval(lo, hi, name: str, n: int) -> tuple[float, float]:
    """``(min, max)`` of a domain of ``n`` equal cells, checked so that the
    arithmetic of sampling stays exact enough: the width ``max - min`` and
    the cell density ``n / width`` finite, and each cell wider than a few
    floats at the domain's magnitude (else cells cannot be told apart and
    ``pdf(sample(u))`` would not be the returned pdf)."""
    for v, which in ((lo, "min"), (hi, "max")):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
            raise TypeError(f"{name} {which} must be a real number; got {type(v).__name__} {v!r}")
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"{name} must be finite with min < max; got ({lo}, {hi})")
    width = hi - lo
    with np.errstate(over="ignore", divide="ignore"):
        density = n / width
    if not (np.isfinite(width) and np.isfinite(density)):
        raise ValueError(f"{name} ({lo}, {hi}) has a width {width} that overflows, or cells of density "
                         f"{n} / {width} that do: keep max - min and {n} / (max - min) finite (rescale the domain)")
    cell = width / n
    if not cell > _MIN_CELL_ULPS * np.spacing(max(abs(lo), abs(hi))):
        raise ValueError(f"{name} ({lo}, {hi}) is too narrow for {n} cells at its magnitude: a cell of width "
                         f"{cell} is not wider than {_MIN_CELL_ULPS} floats ({np.spacing(max(abs(lo), abs(hi)))} "
                         "each); use fewer cells or shift the domain towards 0")
    return lo, hi


def _check_pdf_range(pmf: np.ndarray, density: float, positive=None) -> None:
    """Every cell that can be sampled (``positive``, default ``pmf > 0``) has a
    positive, finite pdf ``pmf * density``: a sampled point of pdf 0 (the
    product underflowing) would be a sample the estimator divides by zero."""
    positive = pmf > 0 if positive is None else positive
    if not np.any(positive):
        return
    with np.errstate(over="ignore", under="ignore"):
        pdf = pmf[positive] * density
    if not (np.all(pdf > 0) and np.all(np.isfinite(pdf))):
        raise ValueError(f"func and domain give a cell whose pdf ({float(pmf[positive].min())} x {density}) "
                         "underflows to 0 or overflows: narrow func's range of values (e.g. set cells below "
                         "1e-250 of its maximum to 0) or rescale the domain")


def _smallest_positive_per_row(pmf: np.ndarray, rows: int = 64) -> np.ndarray:
    """The smallest positive entry of each row (1 for a row without one), a
    few rows at a time (no temporary of the table's size)."""
    out = np.ones(pmf.shape[0])
    for a in range(0, pmf.shape[0], rows):
        block = pmf[a:a + rows]
        out[a:a + rows] = np.min(block, axis=1, where=block > 0, initial=np.inf)
    out[~np.isfinite(out)] = 1.0
    return out


def _unit(u, name: str = "u") -> np.ndarray:
    arr = as_array(u, name)
    if arr.size and not (np.all(arr >= 0.0) and np.all(arr <= 1.0)):
        raise ValueError(f"{name} must lie in [0, 1]; got values in [{arr.min()}, {arr.max()}]")
    return arr


def _cdf_rows(func: np.ndarray) -> np.ndarray:
    """Normalised CDFs of the rows of ``func`` (k, n), shape (k, n + 1), first
    column 0 and last exactly 1; a row of zeros gets the uniform CDF."""
    k, n = func.shape
    cdf = np.zeros((k, n + 1))
    with np.errstate(over="ignore"):
        np.cumsum(func, axis=1, out=cdf[:, 1:])
    totals = cdf[:, -1:].copy()
    if not np.all(np.isfinite(totals)):
        raise ValueError("func must sum to a finite value (scale it down)")
    empty = ~(totals[:, 0] > 0)
    totals[empty] = 1.0
    cdf[:, 1:] /= totals
    cdf[:, -1] = 1.0
    cdf[empty] = np.arange(n + 1) / n
    return cdf


def _last_positive(pmf: np.ndarray) -> np.ndarray:
    """Index of the last cell of non-zero probability in each row of ``pmf``."""
    n = pmf.shape[-1]
    return n - 1 - np.argmax(pmf[..., ::-1] > 0, axis=-1)


def _upper_bound(cdf, values):
    """C++ ``upper_bound``: the first index whose CDF entry is > each value
    (``np.searchsorted(side='right')``). The values are searched in sorted
    order, which lets NumPy reuse each search's bounds for the next: ~10x
    faster for 10^6 values in a 4096 x 2048 map's CDF (cache misses). A
    table of a few entries (a few lights) is searched directly: the sort
    would cost more than it saves."""
    if cdf.size <= _SMALL_TABLE:
        return np.searchsorted(cdf, values, side="right")
    order = np.argsort(values, axis=None)
    flat = values.reshape(-1)
    out = np.empty(flat.shape, dtype=np.int64)
    out[order] = np.searchsorted(cdf, flat[order], side="right")
    return out.reshape(values.shape)


def _searchsorted_rows(cdf_rows, rows, values):
    """``upper_bound`` of ``values[k]`` in row ``rows[k]`` of a 2D array of
    non-decreasing rows: the first column whose entry is > the value, found by
    a binary search vectorised over samples (ceil(log2 W) + 1 gathers, O(n)
    memory; no per-sample Python loop and no ``n x W`` temporary)."""
    w = cdf_rows.shape[1]
    lo = np.zeros(rows.shape, dtype=np.int64)
    hi = np.full(rows.shape, w, dtype=np.int64)
    while True:
        active = lo < hi
        if not active.any():
            return lo
        mid = (lo + hi) // 2
        go_right = active & (cdf_rows[rows, np.minimum(mid, w - 1)] <= values)
        lo = np.where(go_right, mid + 1, lo)
        hi = np.where(active & ~go_right, mid, hi)


def _cell(x, lo: float, hi: float, n: int) -> np.ndarray:
    """Index of the cell of ``x`` among ``n`` equal cells of ``[lo, hi]``,
    clamped to ``[0, n - 1]`` (``x = hi`` is in the last cell)."""
    with np.errstate(invalid="ignore"):
        c = np.floor((x - lo) * (n / (hi - lo)))
    return np.clip(c, 0, n - 1).astype(np.int64)


def _in_cell(k, t, lo: float, hi: float, n: int) -> np.ndarray:
    """The point at fraction ``t`` of cell ``k``, moved by a few ulps where
    rounding would put it into a neighbouring cell (so that a pdf looked up
    at the point is the pdf of the cell it was sampled in)."""
    x = lo + (k + t) * ((hi - lo) / n)
    for _ in range(8):
        c = _cell(x, lo, hi, n)
        if not np.any(c != k):
            break
        x = np.where(c > k, np.nextafter(x, -np.inf), np.where(c < k, np.nextafter(x, np.inf), x))
    return x


class PiecewiseConstant1D:
    """A density on ``[min, max]`` proportional to a piecewise-constant function.

    Parameters
    ----------
    func : array_like, shape (n,)
        Non-negative, finite values on ``n >= 1`` equal cells of
        ``[min, max]``.
    min, max : float
        The domain (pbrt-v4's names), ``min < max``.

    Attributes
    ----------
    cdf : ndarray, shape (n + 1,)
        ``cdf[0] = 0``, ``cdf[n] = 1`` exactly, non-decreasing.
    pmf : ndarray, shape (n,)
        Probability of each cell, ``diff(cdf)``: ``func / func.sum()`` to
        rounding (``1 / n`` each for an all-zero function).
    integral : float
        ``sum(func) (max - min) / n``; 0 for an all-zero function.
    min, max : float
        The domain.

    Notes
    -----
    The density is ``pdf(x) = pmf[o] n / (max - min)`` in cell ``o``, i.e.
    ``func[o] / integral`` (pbrt-v4, sec. A.5.1). See the module docstring
    for ``u = 1``, zero-mass cells and the all-zero function.

    Examples
    --------
    >>> import numpy as np
    >>> d = PiecewiseConstant1D([1.0, 0.0, 3.0])
    >>> x, pdf, offset = d.sample(np.array([0.0, 0.5, 1.0]))
    >>> offset.tolist(), pdf.tolist()
    ([0, 2, 2], [0.75, 2.25, 2.25])
    >>> bool(np.allclose(d.pdf(x), pdf)), d.integral
    (True, 1.3333333333333333)
    """

    def __init__(self, func, min=0.0, max=1.0):  # noqa: A002 (pbrt-v4's names)
        f = as_array(func, "func", ndim=1, nonnegative=True)
        if f.size == 0:
            raise ValueError("func must hold at least one value; got an empty array")
        self.min, self.max = _interval(min, max, "domain", f.size)
        self.cdf = _cdf_rows(f[None, :])[0]
        self.pmf = np.diff(self.cdf)
        self.integral = float(f.sum()) * (self.max - self.min) / f.size
        self._last = int(_last_positive(self.pmf))
        _check_pdf_range(self.pmf, f.size / (self.max - self.min))
        for a in (self.cdf, self.pmf):
            a.flags.writeable = False

    def __len__(self) -> int:
        return int(self.pmf.size)

    @property
    def size(self) -> int:
        """Number of cells ``n``."""
        return int(self.pmf.size)

    def __repr__(self) -> str:
        return f"PiecewiseConstant1D(n={self.size}, min={self.min}, max={self.max}, integral={self.integral:.6g})"

    # -- the sampler ---------------------------------------------------------
    def sample_discrete(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Choose a cell: pbrt-v4's ``SampleDiscrete``, vectorised.

        Parameters
        ----------
        u : array_like
            Uniform numbers in [0, 1] (1.0 included), any shape.

        Returns
        -------
        offset : ndarray of int64
            Cell ``o`` with ``cdf[o] <= u < cdf[o + 1]`` (``upper_bound``);
            never a cell of zero mass (``u = 1`` gives the last cell of
            non-zero mass).
        pmf : ndarray
            Its probability ``pmf[offset]``.
        u_remapped : ndarray
            ``(u - cdf[o]) / pmf[o]``: uniform in [0, 1) again, independent of
            the cell (clipped to [0, 1] against rounding).
        """
        u = _unit(u)
        k = np.minimum(_upper_bound(self.cdf[1:], u), self._last)
        pk = self.pmf[k]
        t = (u - (self.cdf[k + 1] - pk)) / pk
        return k, pk, np.clip(t, 0.0, 1.0)

    def sample(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample ``x`` with density :meth:`pdf` by inverting the CDF.

        Parameters
        ----------
        u : array_like
            Uniform numbers in [0, 1] (1.0 included), any shape.

        Returns
        -------
        x : ndarray
            Values in ``[min, max]``, inside the cell ``offset`` (rounding
            never moves ``x`` into a neighbouring cell).
        pdf : ndarray
            Density per unit ``x``; equals ``self.pdf(x)``.
        offset : ndarray of int64
            The cell of each ``x``.
        """
        k, pk, t = self.sample_discrete(u)
        x = _in_cell(k, t, self.min, self.max, self.size)
        return x, pk * (self.size / (self.max - self.min)), k

    def pdf(self, x) -> np.ndarray:
        """Density per unit ``x`` with which :meth:`sample` produces ``x``;
        0 outside ``[min, max]`` and in cells of zero mass."""
        x = as_array(x, "x")
        inside = (x >= self.min) & (x <= self.max)
        p = self.pmf[_cell(x, self.min, self.max, self.size)] * (self.size / (self.max - self.min))
        return np.where(inside, p, 0.0)

    def invert(self, x) -> np.ndarray:
        """The ``u`` with ``sample(u) = x``: ``cdf[o] + t pmf[o]`` for ``x`` at
        fraction ``t`` of cell ``o`` (pbrt-v4's ``Invert``). In a zero-mass
        cell (never sampled) that is ``cdf[o]`` for every ``x``.

        Raises
        ------
        ValueError
            For ``x`` outside ``[min, max]`` (pbrt-v4 returns no value).
        """
        x = as_array(x, "x")
        if x.size and not (np.all(x >= self.min) and np.all(x <= self.max)):
            raise ValueError(f"x must lie in [min, max] = [{self.min}, {self.max}]; got values in "
                             f"[{x.min()}, {x.max()}]")
        o = _cell(x, self.min, self.max, self.size)
        t = np.clip((x - self.min) * (self.size / (self.max - self.min)) - o, 0.0, 1.0)
        return np.minimum(self.cdf[o] + t * self.pmf[o], 1.0)


class PiecewiseConstant2D:
    """A density on a rectangle proportional to a piecewise-constant function.

    pbrt-v4's ``PiecewiseConstant2D``: a marginal distribution over rows
    (:class:`PiecewiseConstant1D` of the row sums, sampled with ``u[:, 1]``)
    and, in the chosen row, a conditional one over columns (``u[:, 0]``).

    Parameters
    ----------
    func : array_like, shape (nv, nu)
        Non-negative, finite values; row ``i`` covers the ``i``-th slab in the
        second coordinate ``v``, column ``j`` the ``j``-th in the first
        coordinate ``u`` (pbrt-v4's ``func[v * nu + u]``; for an image, row 0
        is the top row).
    domain : ((umin, umax), (vmin, vmax))
        The rectangle; default the unit square.

    Attributes
    ----------
    marginal : PiecewiseConstant1D
        Over rows, on ``[vmin, vmax]``.
    conditional_cdf : ndarray, shape (nv, nu + 1)
        Each row's normalised CDF over columns (uniform for a row of zeros).
    conditional_pmf : ndarray, shape (nv, nu)
        ``diff(conditional_cdf)``; cell ``(i, j)`` has probability
        ``marginal.pmf[i] * conditional_pmf[i, j]``.
    integral : float
        ``sum(func) area / (nu nv)``; 0 for an all-zero function (then
        sampling is uniform over the domain, see the module docstring).

    Notes
    -----
    Memory: two ``nv x nu`` float64 arrays (the conditional CDF and pmf; the
    function itself is not kept). Sampling and pdf evaluation take ``O(n)`` memory for ``n``
    points (vectorised binary searches, no ``n x nu`` temporaries).

    Examples
    --------
    >>> import numpy as np
    >>> d = PiecewiseConstant2D([[0.0, 1.0], [2.0, 1.0]])
    >>> p, pdf, offset = d.sample(np.array([[0.9, 0.1], [0.1, 0.9]]))
    >>> offset.tolist(), pdf.tolist()
    ([[1, 0], [0, 1]], [1.0, 2.0])
    >>> bool(np.allclose(d.pdf(p), pdf)), d.integral
    (True, 1.0)
    """

    def __init__(self, func, domain=((0.0, 1.0), (0.0, 1.0))):
        f = as_array(func, "func", ndim=2, nonnegative=True)
        if f.shape[0] == 0 or f.shape[1] == 0:
            raise ValueError(f"func must have at least one row and one column; got shape {f.shape}")
        try:
            (u0, u1), (v0, v1) = domain
        except (TypeError, ValueError) as exc:
            raise ValueError(f"domain must be ((umin, umax), (vmin, vmax)); got {domain!r}") from exc
        nv, nu = f.shape
        self.domain = (_interval(u0, u1, "domain[0]", nu), _interval(v0, v1, "domain[1]", nv))
        with np.errstate(over="ignore"):
            density = (nu / (u1 - u0)) * (nv / (v1 - v0))
            area = (self.domain[0][1] - self.domain[0][0]) * (self.domain[1][1] - self.domain[1][0])
        if not (np.isfinite(density) and np.isfinite(area) and area > 0):
            raise ValueError(f"domain {self.domain} has an area ({area}) or a cell density per unit area "
                             f"({density}) that overflows: rescale the domain")
        self.marginal = PiecewiseConstant1D(f.sum(axis=1), *self.domain[1])
        self.conditional_cdf = _cdf_rows(f)
        self.conditional_pmf = np.diff(self.conditional_cdf, axis=1)
        self._last_col = _last_positive(self.conditional_pmf)
        _check_pdf_range(self.marginal.pmf * _smallest_positive_per_row(self.conditional_pmf), nu * nv / area,
                         positive=self.marginal.pmf > 0)
        self._area = (self.domain[0][1] - self.domain[0][0]) * (self.domain[1][1] - self.domain[1][0])
        self.integral = float(f.sum()) * self._area / (nu * nv)
        self._shape = (nv, nu)
        for a in (self.conditional_cdf, self.conditional_pmf):
            a.flags.writeable = False

    @property
    def shape(self) -> tuple[int, int]:
        """``(nv, nu)``."""
        return self._shape

    def __repr__(self) -> str:
        return f"PiecewiseConstant2D(shape={self.shape}, domain={self.domain}, integral={self.integral:.6g})"

    # -- the sampler ---------------------------------------------------------
    def sample_discrete(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Choose a cell: the row with ``u[:, 1]``, the column in it with ``u[:, 0]``.

        Parameters
        ----------
        u : array_like, shape (n, 2)
            Uniform numbers in [0, 1]^2 (1.0 included).

        Returns
        -------
        offset : ndarray of int64, shape (n, 2)
            ``(column, row)`` of the cell (pbrt-v4's ``(uOffset, vOffset)``);
            never a cell of zero mass.
        pmf : ndarray, shape (n,)
            Its probability.
        u_remapped : ndarray, shape (n, 2)
            The position inside the cell, uniform in [0, 1)^2.
        """
        u = as_unit_square(u, "u")
        i, p_row, t_v = self.marginal.sample_discrete(u[:, 1])
        cdf = self.conditional_cdf
        # per-row binary search, vectorised: each sample searches its own row
        j = np.minimum(_searchsorted_rows(cdf[:, 1:], i, u[:, 0]), self._last_col[i])
        p_col = self.conditional_pmf[i, j]
        t_u = (u[:, 0] - (cdf[i, j + 1] - p_col)) / p_col
        return (np.stack([j, i], axis=-1), p_row * p_col,
                np.stack([np.clip(t_u, 0.0, 1.0), t_v], axis=-1))

    def sample(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample points with density :meth:`pdf` (per unit area).

        Parameters
        ----------
        u : array_like, shape (n, 2)
            Uniform numbers in [0, 1]^2 (1.0 included).

        Returns
        -------
        points : ndarray, shape (n, 2)
            ``(u, v)`` coordinates in the domain, inside the cell ``offset``.
        pdf : ndarray, shape (n,)
            Density per unit area; equals ``self.pdf(points)``.
        offset : ndarray of int64, shape (n, 2)
            ``(column, row)`` of each point's cell.
        """
        offset, pmf, t = self.sample_discrete(u)
        nv, nu = self.shape
        (u0, u1), (v0, v1) = self.domain
        points = np.stack([_in_cell(offset[:, 0], t[:, 0], u0, u1, nu),
                           _in_cell(offset[:, 1], t[:, 1], v0, v1, nv)], axis=-1)
        return points, pmf * (nu * nv / self._area), offset

    def pdf(self, points) -> np.ndarray:
        """Density per unit area with which :meth:`sample` produces
        ``points`` (n, 2); 0 outside the domain and in cells of zero mass."""
        p = as_points(points, "points", d=2)
        nv, nu = self.shape
        (u0, u1), (v0, v1) = self.domain
        inside = (p[:, 0] >= u0) & (p[:, 0] <= u1) & (p[:, 1] >= v0) & (p[:, 1] <= v1)
        j = _cell(p[:, 0], u0, u1, nu)
        i = _cell(p[:, 1], v0, v1, nv)
        pmf = self.marginal.pmf[i] * self.conditional_pmf[i, j]
        return np.where(inside, pmf * (nu * nv / self._area), 0.0)

    def invert(self, points) -> np.ndarray:
        """The ``u`` (n, 2) with ``sample(u) = points``: the marginal's inverse
        of ``v`` and the chosen row's inverse of ``u`` (pbrt-v4's ``Invert``).

        Raises
        ------
        ValueError
            For points outside the domain.
        """
        p = as_points(points, "points", d=2)
        (u0, u1), (v0, v1) = self.domain
        if p.size and not (np.all((p[:, 0] >= u0) & (p[:, 0] <= u1))
                           and np.all((p[:, 1] >= v0) & (p[:, 1] <= v1))):
            raise ValueError(f"points must lie in the domain {self.domain}")
        nv, nu = self.shape
        i = _cell(p[:, 1], v0, v1, nv)
        j = _cell(p[:, 0], u0, u1, nu)
        t = np.clip((p[:, 0] - u0) * (nu / (u1 - u0)) - j, 0.0, 1.0)
        first = np.minimum(self.conditional_cdf[i, j] + t * self.conditional_pmf[i, j], 1.0)
        return np.stack([first, self.marginal.invert(p[:, 1])], axis=-1)

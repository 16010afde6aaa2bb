"""Domains of :mod:`mcvar.testing`'s checks and per-cell quadrature of a pdf (layer 3).

Each domain is parameterised by a rectangle in coordinates of equal measure:
``(x, y)`` on the square, ``(r^2, phi)`` on the disk, ``(cos theta, phi)``
for directions (normal +y). Private helpers of :mod:`mcvar.testing`.
"""
from __future__ import annotations

import functools
import warnings
from typing import Literal

import numpy as np

from .._validation import as_array


Domain = Literal["square", "disk", "hemisphere", "sphere"]
DOMAINS = ("square", "disk", "hemisphere", "sphere")

_TWO_PI = 2.0 * np.pi
# Parameter rectangle, coordinate names, Jacobian of the parameterisation and
# dimension of the points of each domain. Directions are binned in
# (cos theta, phi): d(omega) = d(cos theta) d(phi), so equal parameter areas
# are equal solid angles; the disk in (r^2, phi): dA = (1/2) d(r^2) d(phi).
_DOMAIN_INFO = {
    "square": (((0.0, 1.0), (0.0, 1.0)), ("x", "y"), 1.0, 2),
    "disk": (((0.0, 1.0), (0.0, _TWO_PI)), ("r^2", "phi"), 0.5, 2),
    "hemisphere": (((0.0, 1.0), (0.0, _TWO_PI)), ("cos_theta", "phi"), 1.0, 3),
    "sphere": (((-1.0, 1.0), (0.0, _TWO_PI)), ("cos_theta", "phi"), 1.0, 3),
}


# --------------------------------------------------------------------------
# domains
# --------------------------------------------------------------------------

def _bounds(domain, bounds):
    full = _DOMAIN_INFO[domain][0]
    if bounds is None:
        return full, True
    b = as_array(bounds, "bounds")
    if b.shape != (2, 2):
        raise ValueError(f"bounds must be ((lo0, hi0), (lo1, hi1)); got shape {b.shape}")
    for k in range(2):
        lo, hi = b[k]
        flo, fhi = full[k]
        if not (flo <= lo < hi <= fhi):
            raise ValueError(f"bounds[{k}] must satisfy {flo} <= lo < hi <= {fhi} for domain "
                             f"{domain!r}; got ({lo}, {hi})")
    bb = ((float(b[0, 0]), float(b[0, 1])), (float(b[1, 0]), float(b[1, 1])))
    return bb, bb == full


def _to_params(x, domain):
    """Parameter coordinates of points ``x`` and a mask of points in the domain."""
    if domain == "square":
        c0, c1 = x[:, 0], x[:, 1]
        tol = 1e-12
        ok = (c0 >= -tol) & (c0 <= 1 + tol) & (c1 >= -tol) & (c1 <= 1 + tol)
        return np.clip(c0, 0, 1), np.clip(c1, 0, 1), ok
    phi_src = (x[:, 0], x[:, 1]) if domain == "disk" else (x[:, 0], x[:, 2])
    phi = np.arctan2(phi_src[1], phi_src[0])
    phi = np.where(phi < 0.0, phi + _TWO_PI, phi)
    phi = np.where(phi >= _TWO_PI, 0.0, phi)
    if domain == "disk":
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        ok = r2 <= 1.0 + 1e-9
        return np.minimum(r2, 1.0), phi, ok
    norm = np.sqrt(np.einsum("ij,ij->i", x, x))
    ok = np.abs(norm - 1.0) <= 1e-6
    y = x[:, 1]
    if domain == "hemisphere":
        ok &= y >= -1e-9
        return np.clip(y, 0.0, 1.0), phi, ok
    return np.clip(y, -1.0, 1.0), phi, ok


def _from_params(c0, c1, domain):
    if domain == "square":
        return np.stack([c0, c1], axis=-1)
    if domain == "disk":
        r = np.sqrt(c0)
        return np.stack([r * np.cos(c1), r * np.sin(c1)], axis=-1)
    s = np.sqrt(np.maximum(0.0, 1.0 - c0 * c0))
    return np.stack([s * np.cos(c1), c0, s * np.sin(c1)], axis=-1)


def _pdf_values(val, m: int, name: str = "pdf") -> np.ndarray:
    """A pdf's output as shape ``(m,)`` float64. A scalar or size-1 array (one
    constant for every point, as Mitsuba 3's uniform-sphere pdf returns) is
    broadcast; any other shape than ``(m,)`` is a ValueError naming ``name``."""
    val = np.asarray(val, dtype=np.float64)
    if val.size == 1 and val.ndim <= 1:
        return np.full(m, float(val.reshape(())))
    if val.shape != (m,):
        raise ValueError(f"{name}(x) must return shape (m,) for m points (or one value for "
                         f"all); got shape {val.shape} for m = {m}")
    return val


def _eval_pdf(pdf, pts, name="pdf"):
    out = np.empty(pts.shape[0])
    step = 1 << 20
    for i in range(0, pts.shape[0], step):
        m = min(step, pts.shape[0] - i)
        out[i:i + step] = _pdf_values(pdf(pts[i:i + step]), m, name)
    return out


# --------------------------------------------------------------------------
# chi-square test
# --------------------------------------------------------------------------

@functools.lru_cache(maxsize=16)
def _gauss_legendre(q):
    nodes, weights = np.polynomial.legendre.leggauss(q)
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


def _cell_integrals(pdf, domain, lo0, hi0, lo1, hi1, q):
    """Integral of the pdf over the cells ``[lo0, hi0] x [lo1, hi1]`` (arrays
    of cell bounds in parameter space) by q-point Gauss-Legendre per axis.

    Returns the integrals and a message if the pdf is negative or not finite
    at some node (else None).
    """
    nodes, weights = _gauss_legendre(q)
    h0, h1 = 0.5 * (hi0 - lo0), 0.5 * (hi1 - lo1)
    m0, m1 = 0.5 * (hi0 + lo0), 0.5 * (hi1 + lo1)
    c0 = m0[:, None, None] + h0[:, None, None] * nodes[None, :, None]
    c1 = m1[:, None, None] + h1[:, None, None] * nodes[None, None, :]
    c0, c1 = np.broadcast_arrays(c0, c1)
    vals = _eval_pdf(pdf, _from_params(c0.ravel(), c1.ravel(), domain)).reshape(c0.shape)
    problem = None if np.all(np.isfinite(vals) & (vals >= 0.0)) else _pdf_problem(vals)
    jac = _DOMAIN_INFO[domain][2]
    integral = np.einsum("kij,i,j->k", vals, weights, weights) * h0 * h1 * jac
    return integral, problem


def _expected_counts(pdf, domain, edges, n, int_tol, q_max=512, budget=4_000_000):
    """Per-cell adaptive Gauss-Legendre: ``q`` doubles only in the cells whose
    expected count is still changing (a discontinuity of the pdf inside them).

    Refinement stops when the change of the last doubling, ``delta``, could
    move the statistic by less than a tenth of its standard deviation
    (``sum(delta^2 / E) <= 0.1 sqrt(2 cells)``) and the integral by less than
    ``int_tol`` (``sum |delta| / n``), or when the node budget is spent.

    Returns ``(expected, chi2_inflation, integral_error, problem)`` where
    ``problem`` is a message when the pdf is negative or not finite somewhere.
    """
    e0, e1 = edges
    b0, b1 = e0.size - 1, e1.size - 1
    i0, i1 = np.meshgrid(np.arange(b0), np.arange(b1), indexing="ij")
    lo0, hi0 = e0[i0.ravel()], e0[i0.ravel() + 1]
    lo1, hi1 = e1[i1.ravel()], e1[i1.ravel() + 1]
    cells = b0 * b1
    allowed = 0.1 * np.sqrt(2.0 * cells)  # a tenth of the statistic's standard deviation
    q = 4
    prev, problem = _cell_integrals(pdf, domain, lo0, hi0, lo1, hi1, q)
    if problem:
        return None, 0.0, 0.0, problem
    expected = n * prev
    err = np.full(cells, np.inf)
    dabs = np.full(cells, np.inf)
    active = np.arange(cells)
    while active.size:
        if 2 * q > q_max or active.size * 4 * q * q > budget:
            break
        q *= 2
        cur, problem = _cell_integrals(pdf, domain, lo0[active], hi0[active],
                                       lo1[active], hi1[active], q)
        if problem:
            return None, 0.0, 0.0, problem
        new = n * cur
        dabs[active] = np.abs(new - expected[active])
        err[active] = dabs[active] ** 2 / np.maximum(new, 1.0)
        expected[active] = new
        if np.sum(err) <= allowed and np.sum(dabs) <= int_tol * n:
            break
        keep = (err[active] > allowed / cells) | (dabs[active] > int_tol * n / cells)
        active = active[keep]
    total_err = float(np.sum(err))
    int_err = float(np.sum(dabs) / n)
    if total_err > allowed:
        warnings.warn(f"chi2_test: pdf quadrature not converged in {active.size} cells "
                      f"(q = {q} nodes per axis; chi-square inflation ~{total_err:.3g}); "
                      "align bin edges with the pdf's discontinuities (bounds=, bins=)",
                      RuntimeWarning, stacklevel=3)
    return expected.reshape(b0, b1), total_err, int_err, None


def _pdf_problem(vals):
    nonfinite = int((~np.isfinite(vals)).sum())
    if nonfinite:
        return f"pdf is NaN or Inf at {nonfinite} quadrature nodes"
    return f"pdf is negative at {int((vals < 0).sum())} quadrature nodes (minimum {np.min(vals):.3g})"

"""Detailed balance and stationarity of one Metropolis step on an analytic target (shared by
test_mcmc and test_pssmlt, which step chains with their own code).

The target on [0,1)^3 is ``f(u) = 2 u_0 * 2 u_1`` (the third coordinate uniform): its exact
samples are ``(sqrt(r_0), sqrt(r_1), r_2)`` and the mass of a cell ``[a, b) x [c, d)`` of the first
two coordinates is ``(b^2 - a^2)(d^2 - c^2)``. The cells' edges (:data:`EDGES`) include thin
cells at both ends of the domain, where a mutation that clips instead of wrapping around
the torus piles up mass. A step of a chain started exactly on ``f`` gives
pairs ``(x_t, x_{t+1})``; on a grid of cells:

* **detailed balance**: the joint counts ``n_ij`` (from cell i to cell j) are symmetric in
  distribution, ``n_ij | n_ij + n_ji ~ Binomial(1/2)``: Bowker's test of symmetry,
  ``sum_{i<j} (n_ij - n_ji)^2 / (n_ij + n_ji) ~ chi^2(pairs)`` (pairs with fewer than 10
  transitions pooled out);
* **stationarity**: the counts of ``x_{t+1}`` against the exact cell masses by Pearson's chi-square.
"""
import numpy as np
from scipy import stats

DIM = 3
#: Cell edges per coordinate (6 cells, 36 in all): thin cells at 0 and 1.
EDGES = np.array([0.0, 0.02, 0.25, 0.5, 0.75, 0.98, 1.0])
CELLS = EDGES.size - 1


def target(u):
    """``f`` on rows ``u`` (n, 3)."""
    return 4.0 * u[:, 0] * u[:, 1]


def exact_samples(n, rng):
    r = rng.random((n, DIM))
    r[:, :2] = np.sqrt(r[:, :2])
    return r


def cell(u):
    k = np.clip(np.searchsorted(EDGES, u[:, :2], side="right") - 1, 0, CELLS - 1)
    return k[:, 0] * CELLS + k[:, 1]


def cell_masses():
    m = np.diff(EDGES ** 2)
    return np.outer(m, m).ravel()


def bowker_pvalue(before, after):
    """Bowker's symmetry test of the transition counts between cells."""
    k = CELLS * CELLS
    n = np.bincount(cell(before) * k + cell(after), minlength=k * k).reshape(k, k)
    i, j = np.triu_indices(k, 1)
    s = n[i, j] + n[j, i]
    keep = s >= 10
    stat = float(((n[i, j] - n[j, i])[keep] ** 2 / s[keep]).sum())
    return float(stats.chi2.sf(stat, int(keep.sum())))


def stationarity_pvalue(after):
    counts = np.bincount(cell(after), minlength=CELLS * CELLS)
    expected = cell_masses() * after.shape[0]
    keep = expected >= 5                       # pool cells expected to hold fewer than 5
    obs = np.append(counts[keep], counts[~keep].sum())
    exp = np.append(expected[keep], expected[~keep].sum())
    if exp[-1] == 0:
        obs, exp = obs[:-1], exp[:-1]
    return float(stats.chisquare(obs, exp).pvalue)

"""Tests of mcvar.piecewise: PiecewiseConstant1D and PiecewiseConstant2D.

Sampling is checked against the pdf by chi-square (mcvar.testing.chi2_test,
bins aligned with the cells, Sidak-corrected over the family); the pdf and the
integral against their closed forms; invert against sample; and the edge cases
of inversion sampling: zero-mass cells, u = 1.0 exactly, one cell, an all-zero
function.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mcvar.piecewise import PiecewiseConstant1D, PiecewiseConstant2D
from mcvar.testing import check_inverse, chi2_test

ALPHA = 1e-3          # family-wise significance of the chi-square tests
CHI2_TESTS = 3        # chi2_test calls in this file (one Sidak family)
N = 200_000
# A cell's probability is a difference of two CDF entries in [0, 1] (what the
# sampler really uses), so it carries an absolute rounding error of a few eps.
EPS4 = 4 * np.finfo(np.float64).eps

# a function with zero cells at both ends and inside, and one huge ratio
F1 = np.array([0.0, 0.0, 1.0, 3.0, 0.0, 0.5, 7.0, 2.0, 0.0, 0.25, 0.0])


def _f2():
    f = np.random.default_rng(20261201).random((6, 9)) ** 2
    f[0] = 0.0            # a zero row at the top
    f[3] = 0.0            # and one inside
    f[:, 4] = 0.0         # a zero column
    f[5, -1] = 0.0        # a zero cell at the end of the last row
    return f


F2 = _f2()


def _positive_mass_u(cdf, rng, n):
    """Uniform numbers away from the CDF's breakpoints (where round trips are exact)."""
    u = rng.random(n)
    return u[np.min(np.abs(u[:, None] - cdf[None, :]), axis=1) > 1e-9]


# ------------------------------------------------------------------ 1D

class TestPiecewiseConstant1D:
    def test_pdf_and_integral_closed_form(self):
        d = PiecewiseConstant1D(F1, -2.0, 3.5)
        width = 5.5 / F1.size
        assert d.integral == pytest.approx(F1.sum() * width, rel=1e-15)
        centres = -2.0 + (np.arange(F1.size) + 0.5) * width
        np.testing.assert_allclose(d.pdf(centres), F1 / d.integral, rtol=0, atol=EPS4 / width)
        np.testing.assert_allclose(d.pmf, F1 / F1.sum(), rtol=0, atol=EPS4)
        assert d.cdf[0] == 0.0 and d.cdf[-1] == 1.0 and np.all(np.diff(d.cdf) >= 0)
        # exactly 0 outside the domain, never NaN
        assert d.pdf(np.array([-2.0001, 3.50001, -1e300])).tolist() == [0, 0, 0]

    def test_chi2_against_pdf(self):
        d = PiecewiseConstant1D(F1)
        # embed in the unit square: x from the distribution, y uniform
        r = chi2_test(lambda u: np.stack([d.sample(u[:, 0])[0], u[:, 1]], axis=1),
                      lambda p: d.pdf(p[:, 0]), "square", n=N, rng=1201, bins=(F1.size, 2),
                      significance=ALPHA, test_count=CHI2_TESTS)
        assert r.passed, r.message

    def test_sample_returns_its_pdf_and_cell(self):
        d = PiecewiseConstant1D(F1, 1.0, 2.0)
        u = np.random.default_rng(7).random(10_000)
        x, pdf, offset = d.sample(u)
        assert x.shape == pdf.shape == offset.shape == u.shape and offset.dtype == np.int64
        assert np.array_equal(d.pdf(x), pdf)
        lo = 1.0 + offset / F1.size
        assert np.all((x >= lo) & (x <= lo + 1.0 / F1.size))
        k, pmf, t = d.sample_discrete(u)
        assert np.array_equal(k, offset) and np.array_equal(pmf, d.pmf[k])
        assert np.all((t >= 0) & (t <= 1))
        # u_remapped is uniform again, independent of the cell: KS test on the
        # remapped numbers of the most likely cell
        assert stats.kstest(t[k == 6], "uniform").pvalue > ALPHA

    def test_zero_mass_cells_never_sampled(self):
        d = PiecewiseConstant1D(F1)
        # every CDF breakpoint, its neighbours in float64, and 0 and 1 exactly
        edges = np.concatenate([d.cdf, np.nextafter(d.cdf, 0.0), np.nextafter(d.cdf, 1.0)])
        u = np.clip(np.concatenate([edges, np.random.default_rng(3).random(100_000)]), 0.0, 1.0)
        x, pdf, offset = d.sample(u)
        assert np.all(F1[offset] > 0)
        assert np.all(pdf > 0) and np.all(d.pdf(x) > 0)

    def test_large_table_zero_cells_and_u_one(self):
        # > 64 cells: the sorted search path (small tables are searched directly)
        f = np.random.default_rng(21).random(5000)
        f[::7] = 0.0
        f[-3:] = 0.0
        d = PiecewiseConstant1D(f)
        u = np.clip(np.concatenate([d.cdf, np.nextafter(d.cdf, 1.0), np.random.default_rng(22).random(50_000)]),
                    0.0, 1.0)
        x, pdf, offset = d.sample(u)
        assert np.all(f[offset] > 0) and np.array_equal(d.pdf(x), pdf)
        assert offset[u == 1.0].tolist() == [4996] * int(np.sum(u == 1.0))
        expected = np.minimum(np.searchsorted(d.cdf[1:], u, side="right"), 4996)
        assert np.array_equal(offset, expected)

    def test_u_one_and_zero_exactly(self):
        d = PiecewiseConstant1D(F1, 0.0, 11.0)
        x, pdf, offset = d.sample(np.array([0.0, 1.0]))
        first, last = np.flatnonzero(F1)[[0, -1]]
        assert offset.tolist() == [first, last]
        assert first <= x[0] <= first + 1 and last <= x[1] <= last + 1
        assert np.array_equal(d.pdf(x), pdf)
        assert d.invert(x[1:]) == pytest.approx(1.0, abs=1e-15)

    def test_single_cell_is_the_uniform_density(self):
        d = PiecewiseConstant1D([2.0], 1.0, 3.0)
        u = np.linspace(0.0, 1.0, 11)
        x, pdf, offset = d.sample(u)
        np.testing.assert_allclose(x, 1.0 + 2.0 * u, rtol=0, atol=1e-15)
        assert np.all(pdf == 0.5) and np.all(offset == 0)
        assert d.integral == 4.0 and len(d) == d.size == 1
        np.testing.assert_allclose(d.invert(x), u, atol=1e-15)

    def test_all_zero_function_falls_back_to_uniform(self):
        d = PiecewiseConstant1D(np.zeros(4), 0.0, 2.0)
        assert d.integral == 0.0
        np.testing.assert_array_equal(d.pmf, np.full(4, 0.25))
        u = np.random.default_rng(11).random(40_000)
        x, pdf, offset = d.sample(u)
        np.testing.assert_allclose(x, 2.0 * u, atol=1e-15)
        assert np.all(pdf == 0.5) and np.all(d.pdf(x) == 0.5)
        counts = np.bincount(offset, minlength=4)
        assert stats.chisquare(counts).pvalue > ALPHA

    def test_invert_round_trips(self):
        d = PiecewiseConstant1D(F1, -1.0, 1.0)
        u = _positive_mass_u(d.cdf, np.random.default_rng(5), 20_000)
        x, _, _ = d.sample(u)
        np.testing.assert_allclose(d.invert(x), u, rtol=0, atol=1e-13)
        # and sample(invert(x)) = x for x in cells of positive mass
        xs = np.random.default_rng(6).uniform(-1.0, 1.0, 20_000)
        xs = xs[F1[np.minimum(((xs + 1.0) / 2.0 * F1.size).astype(int), F1.size - 1)] > 0]
        np.testing.assert_allclose(d.sample(d.invert(xs))[0], xs, rtol=0, atol=1e-13)

    def test_light_selection_by_power(self):
        powers = np.array([0.0, 5.0, 1.0, 0.0, 2.0])
        select = PiecewiseConstant1D(powers)
        np.testing.assert_allclose(select.pmf, powers / powers.sum(), rtol=0, atol=EPS4)
        _, pdf, light = select.sample(np.random.default_rng(17).random(80_000))
        np.testing.assert_allclose(select.pmf[light] * powers.size, pdf, rtol=1e-15)
        counts = np.bincount(light, minlength=powers.size)
        assert counts[0] == counts[3] == 0
        keep = powers > 0
        assert stats.chisquare(counts[keep], 80_000 * select.pmf[keep]).pvalue > ALPHA

    def test_bad_input(self):
        with pytest.raises(ValueError, match="func must be non-negative"):
            PiecewiseConstant1D([1.0, -1.0])
        with pytest.raises(ValueError, match="func must be finite"):
            PiecewiseConstant1D([1.0, np.nan])
        with pytest.raises(ValueError, match="at least one value"):
            PiecewiseConstant1D([])
        with pytest.raises(ValueError, match="func must have 1 dimensions"):
            PiecewiseConstant1D([[1.0]])
        with pytest.raises(ValueError, match="min < max"):
            PiecewiseConstant1D([1.0], 1.0, 1.0)
        with pytest.raises(TypeError, match="domain min"):
            PiecewiseConstant1D([1.0], "0", 1.0)
        with pytest.raises(ValueError, match="finite value"):
            PiecewiseConstant1D([1e308, 1e308])
        d = PiecewiseConstant1D([1.0, 2.0])
        with pytest.raises(ValueError, match=r"u must lie in \[0, 1\]"):
            d.sample([0.5, 1.5])
        with pytest.raises(ValueError, match="u must be finite"):
            d.sample([np.nan])
        with pytest.raises(ValueError, match=r"x must lie in \[min, max\]"):
            d.invert([1.5])
        with pytest.raises(ValueError, match="x must be finite"):
            d.pdf([np.nan])


# ------------------------------------------------------------------ 2D

class TestPiecewiseConstant2D:
    def test_pdf_and_integral_closed_form(self):
        d = PiecewiseConstant2D(F2, domain=((0.0, 2.0), (-1.0, 0.5)))
        nv, nu = F2.shape
        area = 2.0 * 1.5
        assert d.integral == pytest.approx(F2.sum() * area / F2.size, rel=1e-14)
        i, j = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
        centres = np.stack([(j.ravel() + 0.5) * 2.0 / nu, -1.0 + (i.ravel() + 0.5) * 1.5 / nv], axis=1)
        np.testing.assert_allclose(d.pdf(centres), F2.ravel() / d.integral, rtol=0,
                                   atol=2 * EPS4 * F2.size / area)
        assert d.pdf(np.array([[-0.1, 0.0], [1.0, 0.51]])).tolist() == [0.0, 0.0]

    def test_chi2_against_pdf(self):
        d = PiecewiseConstant2D(F2)
        nv, nu = F2.shape
        r = chi2_test(lambda u: d.sample(u)[0], d.pdf, "square", n=N, rng=1202, bins=(nu * 2, nv * 2),
                      significance=ALPHA, test_count=CHI2_TESTS)
        assert r.passed, r.message

    def test_sample_returns_its_pdf_and_cell(self):
        d = PiecewiseConstant2D(F2)
        u = np.random.default_rng(8).random((20_000, 2))
        p, pdf, offset = d.sample(u)
        assert p.shape == offset.shape == (20_000, 2) and pdf.shape == (20_000,)
        assert np.array_equal(d.pdf(p), pdf)
        nv, nu = F2.shape
        assert np.array_equal(np.floor(p * [nu, nv]).astype(int).clip(0, [nu - 1, nv - 1]), offset)
        off, pmf, t = d.sample_discrete(u)
        assert np.array_equal(off, offset)
        np.testing.assert_allclose(pmf, F2[offset[:, 1], offset[:, 0]] / F2.sum(), rtol=0, atol=2 * EPS4)
        assert np.all((t >= 0) & (t <= 1))

    def test_zero_mass_cells_never_sampled(self):
        d = PiecewiseConstant2D(F2)
        rng = np.random.default_rng(4)
        # the marginal's breakpoints crossed with every row's breakpoints, 0 and 1
        v = np.concatenate([d.marginal.cdf, np.nextafter(d.marginal.cdf, 1.0), [0.0, 1.0]])
        w = np.concatenate([d.conditional_cdf.ravel(), np.nextafter(d.conditional_cdf.ravel(), 1.0)])
        u = np.clip(np.stack(np.meshgrid(w, v), axis=-1).reshape(-1, 2), 0.0, 1.0)
        u = np.concatenate([u, rng.random((50_000, 2))])
        p, pdf, offset = d.sample(u)
        assert np.all(F2[offset[:, 1], offset[:, 0]] > 0)
        assert np.all(pdf > 0) and np.array_equal(d.pdf(p), pdf)

    def test_u_one_exactly(self):
        d = PiecewiseConstant2D(F2)
        p, pdf, offset = d.sample(np.array([[1.0, 1.0], [0.0, 0.0]]))
        last_row = np.flatnonzero(F2.sum(axis=1))[-1]
        first_row = np.flatnonzero(F2.sum(axis=1))[0]
        assert offset[0].tolist() == [np.flatnonzero(F2[last_row])[-1], last_row]
        assert offset[1].tolist() == [np.flatnonzero(F2[first_row])[0], first_row]
        assert np.array_equal(d.pdf(p), pdf)

    def test_invert_round_trips(self):
        d = PiecewiseConstant2D(F2)
        rng = np.random.default_rng(9)
        u = rng.random((20_000, 2))
        # away from the breakpoints of the marginal and of the chosen row
        i = d.sample_discrete(u)[0][:, 1]
        far = (np.min(np.abs(u[:, 1:2] - d.marginal.cdf[None, :]), axis=1) > 1e-9) & \
              (np.min(np.abs(u[:, 0:1] - d.conditional_cdf[i]), axis=1) > 1e-9)
        res = check_inverse(lambda q: d.sample(q)[0], d.invert, u=u[far], atol=1e-12)
        assert res.passed, res.message

    def test_single_cell_and_all_zero(self):
        one = PiecewiseConstant2D([[3.0]], domain=((0.0, 2.0), (0.0, 4.0)))
        u = np.random.default_rng(2).random((1000, 2))
        p, pdf, offset = one.sample(u)
        np.testing.assert_allclose(p, u * [2.0, 4.0], atol=1e-15)
        assert np.all(pdf == 1 / 8) and np.all(offset == 0) and one.integral == 24.0
        zero = PiecewiseConstant2D(np.zeros((3, 5)))
        assert zero.integral == 0.0
        p, pdf, offset = zero.sample(u)
        np.testing.assert_allclose(p, u, atol=1e-15)
        np.testing.assert_allclose(pdf, 1.0, rtol=0, atol=2 * EPS4 * 15)
        assert np.array_equal(zero.pdf(p), pdf)

    def test_all_zero_chi2_uniform(self):
        zero = PiecewiseConstant2D(np.zeros((3, 5)))
        r = chi2_test(lambda u: zero.sample(u)[0], zero.pdf, "square", n=N // 4, rng=1203,
                      bins=(10, 6), significance=ALPHA, test_count=CHI2_TESTS)
        assert r.passed, r.message

    def test_bad_input(self):
        with pytest.raises(ValueError, match="func must have 2 dimensions"):
            PiecewiseConstant2D([1.0, 2.0])
        with pytest.raises(ValueError, match="at least one row"):
            PiecewiseConstant2D(np.zeros((0, 3)))
        with pytest.raises(ValueError, match="func must be non-negative"):
            PiecewiseConstant2D([[1.0, -2.0]])
        with pytest.raises(ValueError, match="domain must be"):
            PiecewiseConstant2D([[1.0]], domain=(0.0, 1.0))
        with pytest.raises(ValueError, match="min < max"):
            PiecewiseConstant2D([[1.0]], domain=((0.0, 1.0), (1.0, 0.0)))
        d = PiecewiseConstant2D(F2)
        with pytest.raises(ValueError, match=r"u must lie in \[0, 1\]\^d"):
            d.sample([[0.5, 1.5]])
        with pytest.raises(ValueError, match=r"u must have shape \(n, 2\)"):
            d.sample([[0.5, 0.5, 0.5]])
        with pytest.raises(ValueError, match="points must lie in the domain"):
            d.invert([[0.5, 1.5]])

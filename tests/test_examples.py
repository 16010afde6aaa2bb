"""Tests for mcvar.examples: exact values by independent means, unbiased
methods, analytic variances, and the lecture's examples measured.

Tolerances: means within Z = 5 standard errors; sample variances within Z
standard deviations of s^2, ``sd(s^2)^2 = mu4 / n - sigma^4 (n-3)/(n(n-1))``,
with mu4 the analytic fourth central moment where we have it and the sample's
otherwise (n >= 10^5, so its own error is a few percent of a 5-sd band).
"""
import math

import numpy as np
import pytest
from scipy import integrate, special

from mcvar import warps
from mcvar.estimators import Estimate, convergence_study, estimate, estimate_mean, replicate_study
from mcvar.metrics import loglog_fit
from mcvar.examples import (
    CHECKERBOARD_INTEGRAL,
    CHECKERBOARD_MEAN,
    CHECKERBOARD_VARIANCE,
    INTEGRANDS,
    PROBLEMS,
    checkerboard,
    fixed_grid_estimate,
    hemisphere_problem,
    running_sum,
    single_sample_estimate,
    undivided_estimate,
)

Z = 5.0
ALPHA = 1e-3


def sd_of_sample_variance(var, mu4, n):
    return math.sqrt(max(mu4 / n - var ** 2 * (n - 3) / (n * (n - 1)), 0.0))


# ---------------------------------------------------------------- the lecture's board

def test_checkerboard_values_and_constants():
    assert checkerboard([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5]]).tolist() == [1, 0, 0, 1]
    # exact moments on [0,2]^2 by the midpoint rule, exact for an even grid (no centre on an edge)
    m = 64
    c = (np.arange(m) + 0.5) * 2 / m
    pts = np.stack(np.meshgrid(c, c), axis=-1).reshape(-1, 2)
    f = checkerboard(pts)
    assert f.mean() == CHECKERBOARD_MEAN == 0.5
    assert f.var() == CHECKERBOARD_VARIANCE == 0.25
    assert 4 * f.mean() == CHECKERBOARD_INTEGRAL == 2.0
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        checkerboard(np.zeros((3, 3)))


def test_checkerboard_uniform_variance_4_over_n():
    # Per-sample variance 4 (contributions {0, 4}); the estimator of N samples has 4/N.
    prob = PROBLEMS["checkerboard"]
    assert prob.exact == 2.0 and prob.variances["uniform"] == 4.0
    n = 64

    def run(m, rng):
        return estimate_mean(prob.methods["uniform"], n=m, rng=rng).mean

    s = replicate_study(run, n, replicates=800, exact=2.0, rng=6020)
    var = 4.0 / n
    # mean of 64 scaled Bernoulli(1/2): mu4 = var^2 (3 + kappa/n), kappa = -2
    assert abs(s.variance - var) < Z * sd_of_sample_variance(var, var ** 2 * (3 - 2 / n), 800)


def test_zero_variance_importance_methods():
    u = np.random.default_rng(8080).random((1000, 2))
    u[:4] = [[0, 0], [0, np.nextafter(1, 0)], [0.5, 0.5], [np.nextafter(1, 0), 0]]
    assert np.allclose(PROBLEMS["checkerboard"].methods["importance"](u), 2.0, rtol=0, atol=0)
    for name in ("hemisphere", "hemisphere_cos4"):
        p = PROBLEMS[name]
        assert np.allclose(p.methods["lobe"](u[4:]), p.exact, rtol=1e-12)


# ---------------------------------------------------------------- exact values, independently

@pytest.mark.parametrize("name", ["gaussian", "exp_xy"])
def test_smooth_integrals_by_quadrature(name):
    item = INTEGRANDS[name]
    f = lambda y, x: item.f(np.array([[x, y]]))[0]
    val, err = integrate.dblquad(f, 0, 1, 0, 1, epsabs=1e-12, epsrel=1e-12)
    sq, _ = integrate.dblquad(lambda y, x: f(y, x) ** 2, 0, 1, 0, 1, epsabs=1e-12, epsrel=1e-12)
    assert item.exact == pytest.approx(val, abs=1e-10)
    assert item.variance == pytest.approx(sq - val ** 2, abs=1e-10)


def test_exp_xy_series():
    # int int exp(xy) = sum_k 1 / (k k!)  (expand exp, integrate term by term)
    assert INTEGRANDS["exp_xy"].exact == pytest.approx(sum(1 / (k * math.factorial(k)) for k in range(1, 30)),
                                                       rel=1e-15)


@pytest.mark.parametrize("name", ["diagonal", "rotated_checkerboard"])
def test_half_by_point_reflection(name):
    # f(u) + f(1 - u) = 1 almost everywhere => integral 1/2 (the docstring's proof, checked)
    u = np.random.default_rng(1357).random((100_000, 2))
    f = INTEGRANDS[name].f
    assert np.all(f(u) + f(1.0 - u) == 1.0)
    assert INTEGRANDS[name].exact == 0.5


@pytest.mark.parametrize("name,m", [("step", 3 * 40), ("checkerboard2", 40), ("checkerboard10", 40)])
def test_aligned_indicators_exact_on_grids(name, m):
    # the midpoint grid is exact when every edge lies on cell edges
    assert fixed_grid_estimate(INTEGRANDS[name].f, m) == pytest.approx(INTEGRANDS[name].exact, abs=1e-15)


def test_disk_area():
    assert INTEGRANDS["disk"].exact == pytest.approx(math.pi * 0.16, rel=1e-15)


# ---------------------------------------------------------------- every problem, every method

CASES = [(p, m) for p, prob in PROBLEMS.items() for m in prob.methods]


@pytest.mark.parametrize("problem,method", CASES, ids=[f"{p}-{m}" for p, m in CASES])
def test_methods_unbiased_with_analytic_variance(problem, method):
    prob = PROBLEMS[problem]
    n = 100_000
    y = prob.methods[method](np.random.default_rng(246813579).random((n, 2)))
    assert y.shape == (n,) and np.all(np.isfinite(y))
    e = Estimate.from_samples(y)
    var = prob.variances[method]
    if var == 0.0:
        assert np.allclose(y, prob.exact, rtol=1e-12)
        return
    assert abs(e.mean - prob.exact) < Z * e.stderr
    mu4 = np.mean((y - y.mean()) ** 4)
    assert abs(e.variance - var) < Z * sd_of_sample_variance(var, mu4, n)


@pytest.mark.parametrize("problem", list(PROBLEMS))
def test_methods_at_extremes(problem):
    u = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.5]])
    for g in PROBLEMS[problem].methods.values():
        assert np.all(np.isfinite(g(u))) and g(u[:1]).shape == (1,)


def test_hemisphere_analytic_variances_and_ordering():
    for k in (0.0, 1.0, 4.0):
        p = hemisphere_problem(k)
        assert p.exact == pytest.approx(2 * math.pi / (k + 2))
        v = p.variances
        # 'more radiance per sample': cosine beats uniform; MIS lies between (never worse than the worse)
        assert v["cosine"] < v["mis"] < v["uniform"]
    # k = 1: uniform 4pi^2/5 - (2pi/3)^2 = 16 pi^2 / 45, cosine pi^2/2 - 4pi^2/9 = pi^2 / 18
    v = PROBLEMS["hemisphere"].variances
    assert v["uniform"] == pytest.approx(16 * math.pi ** 2 / 45, rel=1e-14)
    assert v["cosine"] == pytest.approx(math.pi ** 2 / 18, rel=1e-14)


def test_hemisphere_large_k_and_errors():
    p = hemisphere_problem(200.0)
    u = np.random.default_rng(99).random((50_000, 2))
    assert np.allclose(p.methods["lobe"](u), p.exact, rtol=1e-10)
    e = Estimate.from_samples(p.methods["cosine"](u))
    assert abs(e.mean - p.exact) < Z * e.stderr
    with pytest.raises(ValueError, match="k must be >= 0"):
        hemisphere_problem(-1.0)
    with pytest.raises(ValueError, match="k must be finite"):
        hemisphere_problem(float("nan"))


def test_hemisphere_k_very_large():
    # k = 10^4: cos^(k+1) underflows to 0 away from the normal; the lobe still returns the
    # exact 2 pi / (k + 2) at every interior point, and u_0 = 0 exactly (the horizon, where
    # f = p = 0) gives 0, not NaN. The analytic variances stay ordered and positive.
    p = hemisphere_problem(1e4)
    u = np.random.default_rng(31415).random((20_000, 2))
    u[:4] = [[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]]
    y = p.methods["lobe"](u)
    assert y[0] == y[2] == 0.0                      # u_0 = 0: the horizon, measure zero
    assert np.allclose(y[[1, 3]], p.exact, rtol=1e-9)      # u_0 = 1: the normal
    assert np.allclose(y[4:], p.exact, rtol=1e-9)
    v = p.variances
    assert 0 < v["cosine"] < v["mis"] < v["uniform"]
    for method in ("uniform", "cosine", "mis"):
        assert np.all(np.isfinite(p.methods[method](u)))


# ---------------------------------------------------------------- QMC on aligned boards

@pytest.mark.parametrize("sampler", ["sobol", "hammersley"])
def test_qmc_exact_on_power_of_two_boards(sampler):
    # A (0, m, 2)-net with 2^m >= 4 points puts exactly 2^m / 4 points in each quadrant:
    # the 2 x 2 board is integrated exactly, every replicate agrees, the error bar is 0.
    for name in ("checkerboard", "checkerboard2"):
        e = estimate_mean(PROBLEMS[name].methods["uniform"], n=16 * 64, sampler=sampler, rng=5)
        assert e.mean == PROBLEMS[name].exact and e.stderr == 0.0
    e10 = estimate_mean(PROBLEMS["checkerboard10"].methods["uniform"], n=16 * 64, sampler=sampler, rng=5)
    assert e10.stderr > 0 and abs(e10.mean - 0.5) < Z * e10.stderr


# ---------------------------------------------------------------- consistent or unbiased?

def test_grid_estimator_bias_on_the_board():
    # deterministic: bias = error = 2 / m^2 for odd m, 0 for even m (see docstring)
    for m in (1, 3, 5, 9, 31):
        assert fixed_grid_estimate(checkerboard, m, upper=(2, 2)) - 2.0 == pytest.approx(2 / m ** 2, rel=1e-12)
    for m in (2, 4, 10):
        assert fixed_grid_estimate(checkerboard, m, upper=(2, 2)) == 2.0


def test_grid_estimator_consistent_but_biased_on_the_disk():
    disk = INTEGRANDS["disk"]
    ms = np.array([8, 16, 32, 64, 128, 256, 512, 1024])
    err = np.array([abs(fixed_grid_estimate(disk.f, m) - disk.exact) for m in ms])
    assert np.all(err > 0)                  # biased at every finite m ...
    fit = loglog_fit(ms, err)               # ... but consistent: the error falls toward 0
    assert fit.slope < -Z * fit.slope_stderr  # (lattice points in a disk: ~m^-1 with wobble)
    # a replicate study sees zero variance: all of its error is bias
    s = replicate_study(lambda n, rng: fixed_grid_estimate(disk.f, n), 16, replicates=4,
                        exact=disk.exact, rng=1)
    assert s.variance == 0.0 and s.mse == pytest.approx(s.bias ** 2)


def test_single_sample_unbiased_not_consistent():
    # The estimate ignores n. On the board every value is 0 or 4, so |error| = 2 exactly at
    # every n: the error cannot fall. It stays unbiased with variance 4 = 16 * 1/4.
    run = lambda n, rng: single_sample_estimate(checkerboard, upper=(2, 2), rng=rng)
    c = convergence_study(run, [1, 4, 16, 64, 256], replicates=400, exact=2.0, rng=11)
    assert np.all(c.values("rmse") == 2.0)
    for s in c.studies:
        lo, hi = s.bias_ci(1 - ALPHA / 5)
        assert lo < 0 < hi
        assert abs(s.variance - 4.0) < Z * sd_of_sample_variance(4.0, 16.0, 400)
    # on the disk the rmse fluctuates; its fitted slope is 0 within its uncertainty
    disk = INTEGRANDS["disk"]
    run = lambda n, rng: single_sample_estimate(disk.f, rng=rng)
    fit = convergence_study(run, [1, 4, 16, 64, 256], replicates=200, exact=disk.exact, rng=12).fit("rmse")
    assert abs(fit.slope) < Z * fit.slope_stderr
    with pytest.raises(ValueError, match="upper > lower"):
        single_sample_estimate(checkerboard, lower=(1, 1), upper=(0, 2))


# ---------------------------------------------------------------- dividing by the pdf

def test_undivided_importance_sampling_is_biased():
    # L_i = cos^k, f = L cos, cosine sampling: undivided mean -> 2/(k+3), divided -> 2pi/(k+2)
    k = 1
    f = lambda w: np.maximum(w[:, 1], 0.0) ** (k + 1)
    n = 1024
    bad = replicate_study(lambda m, rng: undivided_estimate(f, sample=warps.square_to_cosine_hemisphere,
                                                            n=m, rng=rng), n,
                          replicates=64, exact=2 * math.pi / (k + 2), rng=21)
    good = replicate_study(lambda m, rng: estimate(f, sample=warps.square_to_cosine_hemisphere,
                                                   pdf=warps.square_to_cosine_hemisphere_pdf, n=m, rng=rng),
                           n, replicates=64, exact=2 * math.pi / (k + 2), rng=22)
    lo, hi = bad.bias_ci(1 - ALPHA)
    assert hi < 0                                     # biased, distinguishably
    assert abs(bad.mean - 2 / (k + 3)) < Z * bad.bias_stderr
    lo, hi = good.bias_ci(1 - ALPHA)
    assert lo < 0 < hi
    with pytest.raises(TypeError, match="sample must be callable"):
        undivided_estimate(f, sample=None, n=10)


# ---------------------------------------------------------------- accumulation precision

def test_float32_running_sum_stalls_at_2_24():
    # a constant integrand 1: the float32 sum provably stops at 2^24 (2^24 + 1 is a tie -> even)
    n = (1 << 24) + (1 << 20)
    s32 = running_sum(np.ones(n, dtype=np.float32))
    assert s32[(1 << 24) - 1] == 2.0 ** 24 and s32[-1] == 2.0 ** 24
    assert s32[-1] / n < 1.0 - 0.05                      # running mean 0.94 instead of 1
    # mcvar's accumulation (float64, batched Chan merge) is exact for the same stream
    est = None
    for _ in range(n // (1 << 20)):
        e = Estimate.from_samples(np.ones(1 << 20, dtype=np.float32))
        est = e if est is None else est.merge(e)
    assert est.n == n and est.mean == 1.0 and est.variance == 0.0
    assert running_sum(np.ones(8), dtype=np.float64, initial=2.0 ** 24)[-1] == 2.0 ** 24 + 8


def test_checkerboard_contributions_stall_at_2_26():
    # contributions 4 stall once the spacing is 8: at 2^26 (~3.4e7 samples of mean 2)
    tail = running_sum(np.full(6, 4.0), initial=2.0 ** 26 - 8)
    assert tail.tolist() == [2.0 ** 26 - 4, 2.0 ** 26, 2.0 ** 26, 2.0 ** 26, 2.0 ** 26, 2.0 ** 26]


def test_running_sum_errors():
    with pytest.raises(ValueError, match="1D"):
        running_sum(np.ones((2, 2)))
    with pytest.raises(TypeError, match="floating"):
        running_sum(np.ones(3), dtype=np.int32)
    with pytest.raises(ValueError, match="finite"):
        running_sum([1.0, np.nan])


def test_fixed_grid_errors():
    with pytest.raises(ValueError, match="m must be >= 1"):
        fixed_grid_estimate(checkerboard, 0)
    with pytest.raises(ValueError, match="f must return shape"):
        fixed_grid_estimate(lambda x: np.ones(3), 4)

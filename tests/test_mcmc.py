"""mcvar.mcmc: Metropolis-Hastings, its error bars and the lecture's image walk (issue 12).

Tolerances come from standard errors (5 sigma) or binomial tests; the seeds
are fixed so each statistical test is one draw of a test that would fail
with probability < 1e-3 if the claim were false only by chance.
"""
import math

import numpy as np
import pytest
from scipy import signal, stats
from skimage import data
from skimage.transform import downscale_local_mean

from mcvar import mcmc
from mcvar.estimators import Estimate
from mcvar.mcmc import (Chain, batch_means_time, correlated_estimate, image_walk, integrated_time, metropolis,
                        tv_distance)
from mcvar.testing import sidak_significance

import chain_balance  # tests/chain_balance.py

TWO_PI = 2.0 * np.pi


def cos_bump(u):
    """f(u) = prod_i (1 + cos 2 pi u_i): integral 1, E_{f}[cos 2 pi u_0] = 1/2."""
    return np.prod(1.0 + np.cos(TWO_PI * u), axis=1)


def cos0(u):
    return np.cos(TWO_PI * u[:, 0])


@pytest.fixture(scope="module")
def camera64():
    """The held-aside natural image: skimage's camera, block-averaged to 64 x 64."""
    return downscale_local_mean(data.camera().astype(float), (8, 8))


# -- bad input ----------------------------------------------------------------

@pytest.mark.parametrize("f,match", [
    (lambda u: -np.ones(len(u)), "non-negative"),
    (lambda u: np.full(len(u), np.nan), "non-negative"),
    (lambda u: np.full(len(u), np.inf), "finite"),
    (lambda u: np.ones((len(u), 2)), "shape"),
    (lambda u: np.zeros(len(u)), "zero at all"),
])
def test_bad_target_raises(f, match):
    with pytest.raises(ValueError, match=match):
        metropolis(f, 2, 10, chains=4, n_bootstrap=100, rng=1)


def test_negative_value_found_during_the_walk_raises():
    # positive where the bootstrap looks (x < 0.5), negative elsewhere: found by a mutation
    f = lambda u: np.where(u[:, 0] < 0.5, 1.0, -1.0)
    with pytest.raises(ValueError, match="non-negative"):
        metropolis(f, 1, 200, chains=8, sigma=0.3, n_bootstrap=10, rng=3)


@pytest.mark.parametrize("kw,match", [
    ({"sigma": 0.0}, "sigma"), ({"sigma": -0.1}, "sigma"), ({"sigma": float("nan")}, "sigma"),
    ({"p_large": -0.01}, "p_large"), ({"p_large": 1.5}, "p_large"),
    ({"n_steps": 0}, "n_steps"), ({"chains": 0}, "chains"), ({"dim": 0}, "dim"),
])
def test_bad_parameters_raise(kw, match):
    args = {"f": cos_bump, "dim": 2, "n_steps": 10, **kw}
    with pytest.raises(ValueError, match=match):
        metropolis(args.pop("f"), args.pop("dim"), args.pop("n_steps"), **args)


def test_bad_images_raise():
    with pytest.raises(ValueError, match="image"):
        image_walk(np.zeros((4, 4)), 10)
    with pytest.raises(ValueError, match="image"):
        image_walk(-np.ones((4, 4)), 10)
    with pytest.raises(ValueError, match="image"):
        image_walk(np.ones((4, 4, 2)), 10)
    with pytest.raises(ValueError, match="splat"):
        image_walk(np.ones((4, 4)), 10, splat="fancy")
    with pytest.raises(ValueError, match="sigma"):
        image_walk(np.ones((4, 4)), 10, sigma=0)


# -- the chain's bookkeeping ----------------------------------------------------

def test_chain_shapes_thinning_and_domain(monkeypatch):
    c = metropolis(cos_bump, 3, 50, chains=5, rng=11, n_bootstrap=1000)
    assert isinstance(c, Chain) and c.samples.shape == (50, 5, 3) and c.values.shape == (50, 5)
    assert np.all((c.samples >= 0) & (c.samples < 1))
    np.testing.assert_allclose(c.values, cos_bump(c.samples.reshape(-1, 3)).reshape(50, 5))
    # a step that was rejected leaves the state unchanged
    moved = np.any(c.samples[1:] != c.samples[:-1], axis=2)
    assert np.array_equal(moved, c.accepted[1:])
    # the memory bound: fewer kept steps, the acceptance rate still over all steps
    monkeypatch.setattr(mcmc, "MAX_STORED", 5 * 5 * (3 + 2))   # thin = 50 * 5 * 5 / 125
    t = metropolis(cos_bump, 3, 50, chains=5, rng=11, n_bootstrap=1000)
    assert t.thin == 10 and t.samples.shape == (5, 5, 3)
    assert t.acceptance_rate == c.acceptance_rate      # same stream, same walk


def test_ctrl_c_keeps_the_finished_steps():
    calls = [0]

    def f(u):
        calls[0] += 1
        if calls[0] == 1 + 31:                 # the bootstrap, then 30 steps, then Ctrl-C
            raise KeyboardInterrupt
        return cos_bump(u)

    c = metropolis(f, 2, 100, chains=4, n_bootstrap=500, rng=8)
    assert c.n_steps == 30 and c.samples.shape == (30, 4, 2) and 0 < c.acceptance_rate <= 1
    with pytest.raises(KeyboardInterrupt):     # nothing finished: nothing to keep
        metropolis(lambda u: (_ for _ in ()).throw(KeyboardInterrupt) if len(u) == 4 else cos_bump(u),
                   2, 10, chains=4, n_bootstrap=500, rng=8)


def test_bootstrap_estimates_the_integral():
    # b = integral of prod(1 + cos 2 pi u_i) + 2 = 3 over [0,1)^2
    c = metropolis(lambda u: cos_bump(u) + 2.0, 2, 5, chains=4, rng=2026)
    assert isinstance(c.b, Estimate) and c.b.n == mcmc.N_BOOTSTRAP
    assert abs(c.b.mean - 3.0) < 5 * c.b.stderr


def test_image_walk_bootstrap_is_the_mean_luminance_and_axes(camera64):
    rgb = np.zeros((4, 8, 3))
    rgb[0, 7] = (1.0, 1.0, 1.0)                       # top-right pixel only: luminance 1
    c = image_walk(rgb, 20, chains=3, rng=5, n_bootstrap=4000)
    # x = column (left to right), y = row (top to bottom)
    assert np.all(c.samples[..., 0] >= 7 / 8) and np.all(c.samples[..., 1] < 1 / 4)
    assert c.histogram[0, 7] == 1.0
    w = image_walk(camera64, 5, rng=6)
    assert abs(w.b.mean - camera64.mean()) < 5 * w.b.stderr


# -- statistics of correlated series: analytic AR(1) ------------------------------

def test_integrated_time_of_ar1_matches_theory():
    """AR(1) x_t = phi x_{t-1} + e_t has tau = (1 + phi) / (1 - phi) = 9 for phi = 0.8."""
    phi, n, k = 0.8, 20_000, 8
    rng = np.random.default_rng(20261201)
    e = rng.normal(size=(n + 200, k))
    x = signal.lfilter([1.0], [1.0, -phi], e, axis=0)[200:]
    tau, m = integrated_time(x)
    true = (1 + phi) / (1 - phi)
    se = true * math.sqrt(2 * (2 * m + 1) / x.size)     # Sokal's variance of tau_hat (eq. 3.19)
    assert m >= mcmc.SOKAL_C * tau
    assert abs(tau - true) < 5 * se
    tb = batch_means_time(x, batches=32)
    assert abs(tb - true) < 5 * true * math.sqrt(2 / (32 * k - 1))
    # white noise: tau = 1
    assert abs(integrated_time(e)[0] - 1.0) < 5 * math.sqrt(2 * 11 / e.size) + 0.05
    # a constant series: one effective sample per chain, never NaN
    assert integrated_time(np.ones((7, 2))) == (7.0, 0)


def test_tv_distance():
    assert tv_distance([1, 1, 0, 0], [0, 0, 2, 2]) == 1.0
    assert tv_distance([1, 3], [2, 6]) == 0.0
    assert tv_distance([1, 0], [1, 1]) == 0.5
    with pytest.raises(ValueError):
        tv_distance([1, 2], [1, 2, 3])


# -- the error bars cover ------------------------------------------------------

def test_ess_standard_error_covers_and_naive_iid_under_covers():
    """400 independent chains of 8000 steps estimate E[cos 2 pi u_0] = 1/2 under f.

    Sokal (ESS) and batch-means 95% intervals cover the truth at a rate a
    two-sided binomial test cannot tell from 0.95 (p > 1e-3); the naive iid
    interval, too narrow by sqrt(tau) ~ 3, covers far less (one-sided p < 1e-6).
    """
    reps, n = 400, 8000
    c = metropolis(cos_bump, 2, n, chains=reps, sigma=0.1, p_large=0.02, rng=77)
    x = cos0(c.samples.reshape(-1, 2)).reshape(n, reps)
    covered = {}
    for error in ("sokal", "batch", "naive"):
        hits = 0
        for i in range(reps):
            lo, hi = correlated_estimate(x[:, i], error=error).ci(0.95)
            hits += lo <= 0.5 <= hi
        covered[error] = hits
    assert stats.binomtest(covered["sokal"], reps, 0.95).pvalue > 1e-3, covered
    assert stats.binomtest(covered["batch"], reps, 0.95).pvalue > 1e-3, covered
    assert stats.binomtest(covered["naive"], reps, 0.95, alternative="less").pvalue < 1e-6, covered
    # the chain's own estimate (all chains pooled) agrees with the truth and with its tau
    est = c.estimate(cos0)
    assert abs(est.mean - 0.5) < 5 * est.stderr
    assert c.integrated_time(cos0) > 2.0           # correlated: the naive error bar is too small


# -- acceptance and autocorrelation vs sigma ----------------------------------------

def narrow_bump(u):
    """A Gaussian of width 0.03 at the centre of the square."""
    d = u - 0.5
    return np.exp(-(d * d).sum(axis=1) / (2 * 0.03 ** 2))


def test_acceptance_falls_and_tau_has_a_sweet_spot_in_sigma():
    """On a narrow target, tiny steps are almost always accepted but diffuse
    slowly (large tau); huge steps are mostly rejected (large tau again); tau
    is smallest between (measured: tau ~ 170, 10, 60 at acceptance 0.97,
    0.55, 0.02)."""
    rates, taus = [], []
    for sigma in (0.002, 0.03, 0.5):
        c = metropolis(narrow_bump, 2, 1500, chains=32, sigma=sigma, p_large=0.0, rng=4242)
        per_chain = c.accepted.mean(axis=0)
        rates.append((per_chain.mean(), per_chain.std(ddof=1) / math.sqrt(32)))
        taus.append(c.integrated_time(lambda u: u[:, 0]))
    (r0, s0), (r1, s1), (r2, s2) = rates
    assert r0 - r1 > 5 * math.hypot(s0, s1) and r1 - r2 > 5 * math.hypot(s1, s2)
    assert taus[1] < taus[0] / 3 and taus[1] < taus[2] / 3, taus


# -- ergodicity: the large step ------------------------------------------------

def two_regions():
    img = np.zeros((32, 32))
    img[4:28, 2:10] = 1.0                        # left bright region
    img[4:28, 22:30] = 3.0                       # right, 3x brighter: 3/4 of the mass
    return img


def test_without_large_steps_the_walk_gets_stuck():
    img = two_regions()
    stuck = image_walk(img, 3000, chains=16, sigma=0.01, p_large=0.0, rng=99)
    side = stuck.samples[..., 0] > 0.5                   # (steps, chains): in the right region?
    assert np.all(side == side[0]), "a chain crossed a gap of 12 pixels = 37 sigma"
    free = image_walk(img, 3000, chains=16, sigma=0.01, p_large=0.1, rng=99)
    side = free.samples[..., 0] > 0.5
    crossings = np.count_nonzero(side[1:] != side[:-1], axis=0)
    assert np.all(crossings > 0)
    # one chain (the lecture's walk): stuck, it puts all its mass on one side
    # (truth: 3/4 on the right); with large steps its estimate covers 3/4
    right = lambda u: (u[:, 0] > 0.5).astype(float)
    # and its error bar cannot tell: a constant series has zero spread
    one_stuck = image_walk(img, 8000, sigma=0.01, p_large=0.0, rng=7).estimate(right)
    assert one_stuck.mean in (0.0, 1.0) and one_stuck.stderr == 0.0
    one_free = image_walk(img, 8000, sigma=0.01, p_large=0.1, rng=7).estimate(right)
    assert abs(one_free.mean - 0.75) < 5 * one_free.stderr and one_free.stderr < 0.25 / 3


# -- the lecture's image walk ---------------------------------------------------

def test_image_walk_converges_to_the_image(camera64):
    """TV distance to the normalised image: short walk vs long walk (4 seeds each)."""
    seeds = np.random.SeedSequence(31337).spawn(4)
    short = [tv_distance(image_walk(camera64, 100, chains=16, rng=s).histogram, camera64) for s in seeds]
    long = [tv_distance(image_walk(camera64, 4000, chains=16, rng=s).histogram, camera64) for s in seeds]
    diff = np.mean(short) - np.mean(long)
    se = math.hypot(np.std(short, ddof=1), np.std(long, ddof=1)) / 2
    assert diff > 5 * se and np.mean(long) < np.mean(short) / 3, (short, long)


def test_expected_value_splatting_beats_plain_splatting(camera64):
    """Same walk (same seed), two splats: the expected-value splat is the
    plain splat's conditional expectation, so it is closer to the image;
    paired over 6 seeds, one-sided t-test p < 1e-3."""
    seeds = np.random.SeedSequence(4711).spawn(6)
    plain, expected = [], []
    for s in seeds:
        p = image_walk(camera64, 1500, chains=16, rng=s, splat="plain")
        e = image_walk(camera64, 1500, chains=16, rng=s, splat="expected")
        assert np.array_equal(p.samples, e.samples)
        assert math.isclose(p.histogram.sum(), 1.0) and math.isclose(e.histogram.sum(), 1.0)
        plain.append(tv_distance(p.histogram, camera64))
        expected.append(tv_distance(e.histogram, camera64))
    assert stats.ttest_rel(plain, expected, alternative="greater").pvalue < 1e-3, (plain, expected)


# -- detailed balance of the Kelemen step (issue 22) ---------------------------------------------

@pytest.mark.parametrize("sigma,p_large", [(0.1, 0.3), (0.02, 0.0)])
def test_walk_step_keeps_detailed_balance_and_the_target(sigma, p_large):
    """One step of mcmc's walk (Kelemen's mutation, min(1, f(y)/f(x)), the move) from 200 000
    chains started exactly on f = 4 u0 u1: transitions between the cells symmetric (Bowker),
    the states still distributed as f (chi-square); Sidak over the 4 tests
    (tests/chain_balance.py; a mutation that clips instead of wrapping fails both)."""
    rng = np.random.default_rng(4041)
    x = chain_balance.exact_samples(200_000, rng)
    samples, _, accepted, _, done = mcmc._walk(lambda u: (chain_balance.target(u), None),
                                               (x, chain_balance.target(x), None), 1, (sigma, p_large), rng)
    assert done == 1 and 0.05 < accepted.mean() < 1.0
    alpha = sidak_significance(1e-3, 4)
    assert chain_balance.bowker_pvalue(x, samples[0]) > alpha
    assert chain_balance.stationarity_pvalue(samples[0]) > alpha

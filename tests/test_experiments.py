"""Tests of mcvar.experiments: streams, metrics, verdicts, executors, caches.

The machinery is tested first on synthetic targets whose truth is known by
construction (``_fake_evaluate``: a fixed image plus Gaussian noise of standard
deviation SIGMA / sqrt(spp), plus a bias chosen by the method), then on the
integrands of mcvar.examples and on the Cornell box.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from functools import partial

import re

import numpy as np
import pytest
from scipy import stats

from mcvar import experiments as ex

SIGMA = 0.5
BIAS = 0.2
TRUTH = np.linspace(0.1, 1.0, 4 * 4 * 3).reshape(4, 4, 3)
Z = 5.0  # two-sided alpha ~ 5.7e-7 per check


def _fake_evaluate(method, sampler, spp, rng):
    """Truth + noise; 'unbiased': sigma/sqrt(spp); 'biased': + BIAS (not consistent);
    'vanishing': + BIAS/spp (biased, consistent); 'single': sigma, whatever spp
    (unbiased, not consistent: the lecture's one random sample)."""
    scale = SIGMA if method == "single" else SIGMA / np.sqrt(spp)
    if sampler == "half":  # a 'better sampler': half the noise
        scale = scale / 2
    bias = {"unbiased": 0.0, "single": 0.0, "biased": BIAS, "vanishing": BIAS / spp}[method]
    return TRUTH + bias + scale * rng.standard_normal(TRUTH.shape)


def _fake_reference(rng, *, spp=4096):
    return TRUTH + SIGMA / np.sqrt(spp) * rng.standard_normal(TRUTH.shape)


def fake_target(**kw):
    opts = dict(name="fake", evaluate=_fake_evaluate, key="fake-v1", methods=("unbiased",),
                samplers=("random",), spp=(1, 4, 16, 64), reference_task=_fake_reference,
                reference_chunks=8, reference_settings="spp=4096")
    opts.update(kw)
    return ex.Target(**opts)


class Counting:
    """An evaluate that counts its calls (in-process executors only) and can
    raise KeyboardInterrupt on a given call, like a user pressing Ctrl-C."""

    def __init__(self, interrupt_at=None):
        self.calls = 0
        self.interrupt_at = interrupt_at

    def __call__(self, method, sampler, spp, rng):
        self.calls += 1
        if self.calls == self.interrupt_at:
            raise KeyboardInterrupt
        return _fake_evaluate(method, sampler, spp, rng)


# ---------------------------------------------------------------- streams

def test_run_seed_depends_only_on_configuration():
    a = ex.run_seed(7, "k", "path", "random", 16, 4)
    b = ex.run_seed(7, "k", "path", "random", 16, 4)
    draws = lambda ss: [np.random.default_rng(s).random() for s in ss]  # noqa: E731
    assert draws(a) == draws(b)
    # distinct replicates, and distinct configurations (method, sampler, spp, seed)
    others = [ex.run_seed(7, "k", "direct", "random", 16, 4), ex.run_seed(7, "k", "path", "sobol", 16, 4),
              ex.run_seed(7, "k", "path", "random", 64, 4), ex.run_seed(8, "k", "path", "random", 16, 4)]
    seen = set(draws(a))
    assert len(seen) == 4
    for o in others:
        assert not seen & set(draws(o))


# ---------------------------------------------------------------- metrics

@pytest.fixture(scope="module")
def fake_result():
    target = fake_target(methods=("unbiased", "biased", "vanishing", "single"), samplers=("random", "half"),
                         spp=(1, 4, 16, 64, 256))
    return ex.sweep(target, replicates=16, rng=20240611, workers=1, progress=False)


def test_variance_matches_construction(fake_result):
    # per-pixel variance averaged over P = 48 pixels, each chi^2 with R - 1
    # dof: relative standard deviation sqrt(2 / (P (R - 1))).
    r, p = 16, TRUTH.size
    rel_sd = np.sqrt(2 / (p * (r - 1)))
    for m in fake_result.metrics:
        expected = (SIGMA if m.method == "single" else SIGMA / np.sqrt(m.spp)) ** 2
        expected /= 4 if m.sampler == "half" else 1
        assert abs(m.variance / expected - 1) < Z * rel_sd, m
        # the jackknife error agrees with the analytic one within a factor 2
        assert 0.5 < m.variance_stderr / (expected * rel_sd) < 2, m


def test_bias_squared_is_corrected_for_noise(fake_result):
    for m in fake_result.metrics:
        beta = {"unbiased": 0.0, "single": 0.0, "biased": BIAS, "vanishing": BIAS / m.spp}[m.method]
        assert abs(m.bias2 - beta ** 2) < Z * m.bias2_stderr + 1e-12, m
        assert m.mse == pytest.approx(m.variance + m.bias2)
        assert m.efficiency == pytest.approx(1 / (m.mse * m.seconds))
        assert m.figure_of_merit == pytest.approx(m.mse * m.seconds)


def test_one_replicate_statistics_and_efficiency_with_estimators(fake_result):
    # experiments and mcvar.estimators.ReplicateStudy share one implementation
    # (replicate_moments) and one efficiency definition, 1 / (MSE x time)
    from mcvar.estimators import efficiency, replicate_moments

    ref = fake_result.reference
    for m in fake_result.metrics:
        values = fake_result.values[(m.method, m.sampler, m.spp)]
        assert replicate_moments(values, ref.value, ref.variance) == (m.variance, m.bias2, m.mse)
        assert m.mse == pytest.approx(m.variance + m.bias2, rel=1e-12, abs=1e-15)
        assert m.efficiency == efficiency(m.mse, m.seconds)


def test_bias_test_and_verdicts(fake_result):
    v = fake_result.verdicts
    assert (v["unbiased"].label, v["biased"].label, v["vanishing"].label, v["single"].label) == \
        ("both", "neither", "consistent", "unbiased")
    for m in fake_result.metrics:
        if m.method == "biased":
            assert m.bias_detected and m.bias_z > Z
        if m.method in ("unbiased", "single"):
            assert not m.bias_detected
    assert "Sidak" in v["biased"].evidence


def test_variance_slope_is_minus_one_for_iid_noise(fake_result):
    fit = fake_result.fits[("unbiased", "random")].variance
    lo, hi = fit.slope_ci(1 - 1e-3)
    assert lo <= -1 <= hi
    assert fake_result.fits[("single", "random")].variance.slope_ci(1 - 1e-3)[0] <= 0


def test_rows_hold_every_number(fake_result):
    rows = fake_result.rows()
    assert len(rows) == len(fake_result.metrics) == 4 * 2 * 5
    assert {"variance", "bias2", "mse", "rel_mse", "seconds", "efficiency", "bias_pvalue",
            "mse_x_time"} <= set(rows[0])
    pv = fake_result.pixel_variance("unbiased", "random", 1)
    assert pv.shape == TRUTH.shape


# ---------------------------------------------------------------- executors, caches

def _numbers(result):
    skip = {"seconds", "efficiency", "mse_x_time"}  # wall time differs between executors
    return [{k: v for k, v in row.items() if k not in skip} for row in result.rows()]


def test_serial_process_and_dask_executors_agree(tmp_path):
    target = fake_target(spp=(1, 4, 16))
    kw = dict(replicates=4, rng=99991, progress=False, methods=("unbiased", "biased"))
    serial = ex.sweep(target, workers=1, **kw)
    with ProcessPoolExecutor(max_workers=2) as pool:
        process = ex.sweep(target, executor=pool, **kw)
    distributed = pytest.importorskip("distributed")
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2,
                            dashboard_address=None) as client:
        dask = ex.sweep(target, executor=client.get_executor(), **kw)
    for other in (process, dask):
        assert _numbers(other) == _numbers(serial)
        for key, value in serial.values.items():
            np.testing.assert_array_equal(other.values[key], value)


def test_interrupted_sweep_resumes_without_recomputing(tmp_path):
    kw = dict(replicates=3, rng=4242, progress=False, cache_dir=tmp_path, workers=1)
    total = 2 * 3 * 3
    first = Counting(interrupt_at=7)
    with pytest.raises(KeyboardInterrupt):
        ex.sweep(fake_target(evaluate=first, spp=(1, 4, 16)), samplers=("random", "half"), **kw)
    assert first.calls == 7
    second = Counting()
    resumed = ex.sweep(fake_target(evaluate=second, spp=(1, 4, 16)), samplers=("random", "half"), **kw)
    assert second.calls == total - 6 and resumed.computed == total - 6 and resumed.cached == 6
    third = Counting()
    again = ex.sweep(fake_target(evaluate=third, spp=(1, 4, 16)), samplers=("random", "half"), **kw)
    assert third.calls == 0 and again.cached == total
    assert _numbers(again) == _numbers(resumed)
    # and the resumed numbers equal an uninterrupted run's
    fresh = ex.sweep(fake_target(spp=(1, 4, 16)), samplers=("random", "half"),
                     **{**kw, "cache_dir": tmp_path / "fresh"})
    assert _numbers(fresh) == _numbers(resumed)


def test_reference_is_cached_and_its_variance_measured(tmp_path):
    calls = []

    def task(rng):
        calls.append(1)
        return _fake_reference(rng)

    target = fake_target(reference_task=task)
    ref = ex.compute_reference(target, rng=5, cache_dir=tmp_path)
    assert len(calls) == 8 and ref.chunks == 8 and ref.source.startswith("rendered")
    # variance of the mean of 8 chunks of 4096 spp each: sigma^2 / (8 * 4096);
    # pixel-average of chi^2_7 / 7 estimates: relative sd sqrt(2 / (48 * 7)).
    expected = SIGMA ** 2 / (8 * 4096)
    assert abs(ref.variance.mean() / expected - 1) < Z * np.sqrt(2 / (TRUTH.size * 7))
    again = ex.compute_reference(target, rng=5, cache_dir=tmp_path)
    assert len(calls) == 8 and again.source.startswith("cache")
    np.testing.assert_array_equal(again.value, ref.value)
    ex.compute_reference(target, rng=6, cache_dir=tmp_path)  # another seed: another key
    assert len(calls) == 16


def test_reference_from_user_file(tmp_path):
    np.save(tmp_path / "ref.npy", TRUTH)
    ref = ex.compute_reference(fake_target(), path=tmp_path / "ref.npy")
    np.testing.assert_array_equal(ref.value, TRUTH)
    assert np.all(ref.variance == 0) and ref.source.startswith("file")
    result = ex.sweep(fake_target(spp=(1, 4, 16)), reference=tmp_path / "ref.npy", replicates=4,
                      rng=11, workers=1, progress=False)
    assert result.verdicts["unbiased"].unbiased
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ex.compute_reference(fake_target(), path=tmp_path / "missing.npy")


# ---------------------------------------------------------------- bad input

def test_bad_input():
    with pytest.raises(ValueError, match="replicates must be >= 3"):
        ex.sweep(fake_target(), replicates=2, workers=1, progress=False)
    with pytest.raises(ValueError, match="spp must be >= 1"):
        ex.sweep(fake_target(), spp=[0, 4], workers=1, progress=False)
    with pytest.raises(ValueError, match="methods must be a non-empty"):
        ex.sweep(fake_target(), methods=[], workers=1, progress=False)
    with pytest.raises(TypeError, match="executor must be"):
        ex.sweep(fake_target(), executor="pool", progress=False)
    with pytest.raises(ValueError, match="method must look like"):
        ex.parse_method("path:0")
    with pytest.raises(TypeError, match="target must be"):
        ex.make_target(3)
    with pytest.raises(ValueError, match="shape"):
        ex.sweep(fake_target(spp=(1, 4, 16)), reference=ex.Reference(np.zeros(3), np.zeros(3), 0.0, 0, "x"),
                 replicates=3, workers=1, progress=False)


def _nan_evaluate(method, sampler, spp, rng):
    return np.full(3, np.nan)


def test_non_finite_estimates_are_an_error():
    with pytest.raises(ValueError, match="non-finite"):
        ex.sweep(fake_target(evaluate=_nan_evaluate, exact=np.zeros(3)), spp=(1, 2, 4), replicates=3,
                 workers=1, progress=False)


# ---------------------------------------------------------------- the Cornell box

def test_fixed_depth_path_tracing_is_biased_and_russian_roulette_is_not():
    """The lecture's 'Number of ray bounces' and the chart's 'path tracing':
    stopping paths at depth 2 loses the indirect light (a bias detected at more
    than 5 standard errors); Russian roulette's bias is not detected."""
    pytest.importorskip("mcvar.integrators")
    target = ex.scene_target("cornell", res=16, reference_spp=256, reference_chunks=8)
    result = ex.sweep(target, methods=("path", "path:2"), samplers=("random",), spp=(4, 32, 256),
                      replicates=8, rng=271828, workers=1, progress=False)
    fixed = [m for m in result.metrics if m.method == "path:2"]
    rr = [m for m in result.metrics if m.method == "path"]
    assert fixed[-1].bias_z < -Z  # light is missing: the bias is negative
    assert all(m.bias_pvalue > result.alpha_family for m in rr)
    assert result.verdicts["path"].label == "both"
    assert result.verdicts["path:2"].label == "neither"  # its MSE levels off at the squared bias


# ---------------------------------------------------------------- integrands (mcvar.examples)

def test_plain_random_monte_carlo_variance_falls_as_one_over_n():
    """Checkerboard, uniform sampling: Var = 4 / N ('Variance Reduction
    Example': integrand variance 1/4, contribution 4 f, so 16 / 4 per sample)."""
    result = ex.sweep("checkerboard", methods=("uniform",), samplers=("random",), replicates=32,
                      rng=1618033, workers=1, progress=False)
    fit = result.fits[("uniform", "random")].variance
    lo, hi = fit.slope_ci(1 - 1e-3)  # Student t, n - 2 dof, from the fit's residuals
    assert lo <= -1 <= hi
    # each level: R - 1 = 31 dof; the sample variance of a 0/4-valued mean is
    # not Gaussian, so use its exact sampling sd sqrt(mu4/R - s^4 (R-3)/(R(R-1)))
    for m in result.metrics:
        r, n = m.replicates, m.spp
        var = 4.0 / n
        # fourth central moment of the mean of n iid contributions 4 f = 2 +- 2
        # (sigma^2 = 4, mu4 = 16): mu4 / n^3 + 3 (n - 1) sigma^4 / n^3
        mu4 = (16.0 + 3 * (n - 1) * 16.0) / n ** 3
        sd = np.sqrt(mu4 / r - var ** 2 * (r - 3) / (r * (r - 1)))
        assert abs(m.variance - var) < Z * sd, m
    assert result.verdicts["uniform"].label == "both"


def test_stratified_and_qmc_beat_random_on_a_smooth_integrand():
    """exp(xy) on [0,1]^2: jittered sampling's variance falls like N^-2 in 2D
    (Mitchell 1996), scrambled Sobol's faster still; random stays at N^-1."""
    result = ex.sweep("exp_xy", samplers=("random", "jittered", "sobol"), spp=(4, 16, 64, 256, 1024, 4096),
                      replicates=16, rng=577215, workers=1, progress=False)
    fit = {s: result.fits[("uniform", s)].variance for s in result.samplers}
    # one-sided test that the slope is steeper than random's: the difference
    # over its standard error against Student t with 2 (n - 2) dof at 1 - 1e-3
    for s in ("jittered", "sobol"):
        t = (fit["random"].slope - fit[s].slope) / np.hypot(fit["random"].slope_stderr, fit[s].slope_stderr)
        assert t > stats.t.ppf(1 - 1e-3, 2 * (fit[s].n - 2)), (s, fit[s], fit["random"])
    # from N = 16 on, the variance ratio random / other exceeds the F(R-1, R-1)
    # quantile at 1 - 1e-3: the improvement is significant, level by level
    # (at N = 4 two strata per axis gain only a factor 3-7)
    f_crit = stats.f.ppf(1 - 1e-3, 15, 15)
    for n in result.spp[1:]:
        v = {m.sampler: m.variance for m in result.metrics if m.spp == n}
        assert v["random"] / v["jittered"] > f_crit and v["random"] / v["sobol"] > f_crit


def test_the_lectures_estimators_get_the_lectures_verdicts():
    """'Bias & Consistency', 'Consistent Or Unbiased?', 'Biased vs. Unbiased
    Example': plain MC is both, the m x m grid consistent only, one sample
    times the area unbiased only, not dividing by the pdf neither."""
    result = ex.sweep("lecture", replicates=16, rng=141421, workers=1, progress=False)
    labels = {m: v.label for m, v in result.verdicts.items()}
    assert labels == {"uniform": "both", "grid": "consistent", "single": "unbiased", "undivided": "neither"}
    grid = [m for m in result.metrics if m.method == "grid"]
    # fixed_grid_estimate's bias on the board is exactly 2 / m^2 for odd m
    for m in grid:
        assert m.variance == 0 and m.bias == pytest.approx(2 / m.spp, rel=1e-12)
    undivided = [m for m in result.metrics if m.method == "undivided"]
    assert undivided[-1].bias == pytest.approx(0.5 - 2.0, abs=Z * undivided[-1].bias_stderr)


def _zero_variance_evaluate(method, sampler, spp, rng):
    # 'exact': an estimator with zero variance whose float64 result differs from
    # the exact value by rounding only (one or two ulps at some levels);
    # 'offset': zero variance and a real bias of 1e-9.
    exact = 2.0 * np.pi / 3.0
    value = exact
    for _ in range(spp % 3):
        value = np.nextafter(value, np.inf)
    return np.array([value + (1e-9 if method == "offset" else 0.0)])


def test_zero_variance_estimators_are_judged_by_rounding_not_by_z_infinity():
    target = ex.Target(name="zero-variance", evaluate=_zero_variance_evaluate, key="zero-variance-v1",
                       methods=("exact", "offset"), samplers=("random",), spp=(1, 3, 7, 49),
                       exact=np.array([2.0 * np.pi / 3.0]))
    result = ex.sweep(target, replicates=4, rng=3, executor=ex.SerialExecutor(), progress=False)
    assert result.verdicts["exact"].label == "both"  # exact at every level, up to rounding
    assert result.verdicts["offset"].label == "neither"  # biased, and the bias never falls



def test_zero_variance_evidence_states_the_exact_bias_not_a_rounding_t(tmp_path):
    """A deterministic estimator's bias is its error, known exactly: the evidence
    and the report say 'bias = X exactly', not |t| = bias / rounding floor (~1e13)."""
    from mcvar.report import write_report

    grid = ex.sweep("lecture", methods=["grid"], replicates=4, rng=5, workers=1, progress=False)
    assert all(m.deterministic and m.bias_detected for m in grid.metrics)
    assert abs(grid.metrics[0].bias_z) > 1e12  # the number the text must not show
    ev = grid.verdicts["grid"].evidence
    assert "|t|" not in ev and "t = " not in ev and "e+1" not in ev
    assert "zero variance in 5 of 5 configurations" in ev and "bias nonzero beyond rounding in 5" in ev
    for m in grid.metrics:  # fixed_grid_estimate's bias on the board is 2 / m^2 for odd m
        assert f"{2 / m.spp:+.4g} (random, {m.spp} spp)" in ev
    page = write_report(grid, tmp_path)["html"].read_text()
    page = re.sub(r"data:[^\"')\s]+", "", page)  # embedded images' base64 may contain 'e+1' by chance
    assert "exact (zero variance)" in page and "e+1" not in page

    target = ex.Target(name="zero-variance", evaluate=_zero_variance_evaluate, key="zero-variance-v1",
                       methods=("exact", "offset"), samplers=("random",), spp=(1, 3, 7, 49),
                       exact=np.array([2.0 * np.pi / 3.0]))
    result = ex.sweep(target, replicates=4, rng=3, executor=ex.SerialExecutor(), progress=False)
    assert "bias = 0 (to rounding) (random, 1 spp)" in result.verdicts["exact"].evidence
    assert "nonzero beyond rounding in 4: bias = +1e-09 (random, 1 spp)" in result.verdicts["offset"].evidence
    # an estimator that scatters keeps its t test
    noisy = ex.sweep("lecture", methods=["uniform"], spp=[1, 9, 49], replicates=4, rng=5, workers=1,
                     progress=False)
    assert not any(m.deterministic for m in noisy.metrics)
    assert "largest |t| = " in noisy.verdicts["uniform"].evidence

def _scalar_evaluate(method, sampler, spp, rng):
    # Heavy-ish tails like a Monte Carlo contribution; 'mc' averages spp of them,
    # 'single' is the lecture's one random sample whatever spp says.
    n = 1 if method == "single" else spp
    return np.array([1.0 + rng.exponential(1.0, n).mean() - 1.0])


def test_consistency_of_a_scalar_estimator_is_detected_from_few_replicates():
    # With 8 replicates the MSE at N = 1 has a relative error ~0.5, so a
    # first-vs-last comparison alone cannot reach the Sidak-corrected level:
    # the slope over all levels must carry the verdict.
    target = ex.Target(name="scalar", evaluate=_scalar_evaluate, key="scalar-v1",
                       methods=("mc", "single"), samplers=("random",),
                       spp=tuple(4 ** k for k in range(7)), exact=np.array([1.0]))
    result = ex.sweep(target, replicates=8, rng=11, executor=ex.SerialExecutor(), progress=False)
    assert result.verdicts["mc"].label == "both"
    assert result.verdicts["single"].label == "unbiased"


def test_integrand_sweeps_randomize_deterministic_samplers():
    # Hammersley ignores rng: without a per-replicate shift every replicate
    # would be the same number and the variance exactly 0.
    result = ex.sweep(ex.integrand_target("hemisphere"), methods=["uniform"], samplers=["hammersley"],
                      spp=[16, 64, 256], replicates=6, rng=5, executor=ex.SerialExecutor(), progress=False)
    assert all(m.variance > 0 for m in result.metrics)
    assert result.verdicts["uniform"].unbiased


def test_rng_is_the_word_and_seed_a_deprecated_alias(tmp_path):
    """sweep, compute_reference, run_seed, measure_chart, convergence_report, chart_report and the
    samplers report take rng=; seed= still works (the same numbers) with a DeprecationWarning."""
    from mcvar.sampler_report import discrepancy_sweep

    kw = dict(methods=("uniform",), spp=[1, 4, 16], replicates=4, workers=1, progress=False)
    new = ex.sweep("lecture", rng=5, **kw)
    with pytest.warns(DeprecationWarning, match=r"sweep\(seed=...\) is deprecated"):
        old = ex.sweep("lecture", seed=5, **kw)
    assert all(np.array_equal(new.values[k], old.values[k]) for k in new.values)
    with pytest.raises(TypeError, match="both rng= and its deprecated alias seed="):
        ex.sweep("lecture", rng=5, seed=5, **kw)
    with pytest.raises(TypeError, match="rng must be an integer seed >= 0 here"):
        ex.sweep("lecture", rng=np.random.default_rng(5), **kw)
    with pytest.raises(TypeError, match="unexpected keyword argument.*'replicate'"):
        ex.sweep("lecture", replicate=4)
    with pytest.warns(DeprecationWarning):
        assert discrepancy_sweep([16], names=["random"], seed=3) == discrepancy_sweep([16], names=["random"], rng=3)
    # a settings record is the same as its keywords
    settings = ex.SweepSettings(methods=("uniform",), spp=(1, 4, 16), replicates=4, rng=5, workers=1,
                                progress=False)
    again = ex.sweep("lecture", settings)
    assert all(np.array_equal(new.values[k], again.values[k]) for k in new.values)

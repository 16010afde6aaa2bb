"""The pieces of ``benchmarks/bench_suite.py`` that can be wrong without Mitsuba: the
reference's variance from independent chunks, the MSE minus the reference's floor,
the image-mean agreement z-score, the efficiency ratio and its geometric mean."""
from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def suite():
    spec = importlib.util.spec_from_file_location("bench_suite", ROOT / "benchmarks" / "bench_suite.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_suite"] = mod            # its dataclass looks its module up
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop("bench_suite", None)


def test_reference_variance_is_that_of_the_mean_of_k_chunks(suite):
    """Chunks of known per-pixel variance s^2: the returned variance of the mean averages
    to s^2 / K (its pixels' mean is known to the chi-square's standard error)."""
    rng = np.random.default_rng(11)
    k, shape, s = 16, (40, 50, 3), 0.3
    chunks = 2.0 + s * rng.standard_normal((k, *shape))
    mean, var = suite.reference_from_chunks(chunks)
    np.testing.assert_allclose(mean, chunks.mean(axis=0))
    n = np.prod(shape)
    want = s ** 2 / k
    se = want * math.sqrt(2.0 / (k - 1) / n)          # var of a chi-square_{k-1} / (k-1) per pixel
    assert abs(var.mean() - want) < 5 * se, (var.mean(), want, se)
    with pytest.raises(ValueError, match="at least 2"):
        suite.reference_from_chunks(chunks[:1])


def test_mse_minus_floor_recovers_the_true_mse_with_a_noisy_reference(suite):
    """Truth T; the reference is the mean of K noisy chunks (sigma_r); the image has
    error sigma_x. mean((x - ref)^2) is sigma_x^2 + sigma_r^2 / K; minus the floor it is
    sigma_x^2, within 5 standard errors over replicates (the uncorrected MSE is not)."""
    rng = np.random.default_rng(12)
    shape, k, sig_x, sig_r = (32, 32, 3), 8, 0.01, 0.05          # floor 3.1e-4 >> MSE 1e-4
    truth = rng.uniform(0, 1, shape)
    got, raw = [], []
    for _ in range(40):
        ref, ref_var = suite.reference_from_chunks(truth + sig_r * rng.standard_normal((k, *shape)))
        x = truth + sig_x * rng.standard_normal(shape)
        got.append(suite.mse_minus_floor(x, ref, ref_var))
        raw.append(float(np.mean((x - ref) ** 2)))
    got = np.asarray(got)
    se = got.std(ddof=1) / math.sqrt(got.size)
    assert abs(got.mean() - sig_x ** 2) < 5 * se, (got.mean(), sig_x ** 2, se)
    assert np.mean(raw) - sig_x ** 2 > 20 * se                 # without the floor: biased
    # exact identity: an image equal to the reference has MSE minus floor = -floor
    assert suite.mse_minus_floor(ref, ref, ref_var) == pytest.approx(-float(ref_var.mean()), rel=1e-12)


def test_mse_minus_floor_refuses_mismatched_or_bad_input(suite):
    a = np.zeros((4, 4, 3))
    with pytest.raises(ValueError, match="one shape"):
        suite.mse_minus_floor(a, a[:2], a)
    with pytest.raises(ValueError, match=">= 0"):
        suite.mse_minus_floor(a, a, a - 1.0)
    with pytest.raises(ValueError, match="finite"):
        suite.mse_minus_floor(a + np.nan, a, a)


def test_mean_z_scores_are_standard_normal_when_unbiased_and_large_when_biased(suite):
    """Unbiased images: the z-scores over many replicates are N(0, 1) (Kolmogorov-Smirnov,
    with only 3 images each: the Student-t conversion is what makes that hold); an image
    offset by 10 standard errors of its mean is flagged."""
    rng = np.random.default_rng(13)
    shape, k, n = (8, 8, 3), 16, 3
    truth = rng.uniform(0, 1, shape)
    zs = []
    for _ in range(300):
        # a precise reference: the images' 2 degrees of freedom dominate, as with 3 renders
        ref, ref_var = suite.reference_from_chunks(truth + 0.02 * rng.standard_normal((k, *shape)))
        images = truth + 0.1 * rng.standard_normal((n, *shape))
        zs.append(suite.mean_z_scores(images, ref, ref_var, k - 1))
    zs = np.concatenate(zs)
    assert stats.kstest(zs, "norm").pvalue > 1e-3
    # the tail: P(|z| > 3) = 0.27 % for a normal z (Student's t with 2 dof: 9.5 %)
    p3 = 2 * stats.norm.sf(3.0)
    assert np.mean(np.abs(zs) > 3) < p3 + 5 * math.sqrt(p3 * (1 - p3) / zs.size)
    # a bias of 10 standard errors (of the images' mean image mean, known exactly here)
    se = math.sqrt(0.1 ** 2 / (n * 64) + 0.2 ** 2 / k / 64)
    images = truth + 10 * se + 0.1 * rng.standard_normal((n, *shape))
    ref, ref_var = suite.reference_from_chunks(truth + 0.2 * rng.standard_normal((k, *shape)))
    assert np.all(np.abs(suite.mean_z_scores(images, ref, ref_var, k - 1)) > 2.5)
    with pytest.raises(ValueError, match="n >= 2"):
        suite.mean_z_scores(images[:1], ref, ref_var)


def test_ratio_and_geometric_mean(suite):
    # Mitsuba 4e-6 x 0.3 s against mcvar 5e-6 x 0.9 s: 1.2e-6 / 4.5e-6
    assert suite.efficiency_ratio(4e-6, 0.3, 5e-6, 0.9) == pytest.approx(1.2e-6 / 4.5e-6, rel=1e-12)
    assert suite.efficiency_ratio(1e-5, 1.0, 1e-5, 0.5) == pytest.approx(2.0)
    assert math.isnan(suite.efficiency_ratio(1e-5, 1.0, -1e-7, 0.5))      # MSE below the floor
    assert suite.geometric_mean([0.5, 2.0, 4.0, 0.25]) == pytest.approx(1.0, rel=1e-12)
    assert suite.geometric_mean([0.86, 0.66, 0.80, 0.20]) == pytest.approx((0.86 * 0.66 * 0.80 * 0.20) ** 0.25)
    assert suite.geometric_mean([2.0, float("nan"), 8.0]) == pytest.approx(4.0)
    with pytest.raises(ValueError, match="positive"):
        suite.geometric_mean([1.0, 0.0])


def test_summary_uses_median_seconds_and_mean_mse(suite):
    s = suite.summarize([1.0, 9.0, 2.0], [1e-5, 2e-5, 6e-5], paths=2e6)
    assert s["seconds"] == 2.0 and s["mse"] == pytest.approx(3e-5)
    assert s["mse_x_time"] == pytest.approx(6e-5) and s["s_per_mpath"] == pytest.approx(1.0)
    assert s["mse_se"] == pytest.approx(np.std([1e-5, 2e-5, 6e-5], ddof=1) / math.sqrt(3))


def test_find_libllvm_prefers_what_it_is_given(suite, monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/x/libLLVM.so.19.1")
    assert suite.find_libllvm("/given/libLLVM-17.so") == "/given/libLLVM-17.so"
    assert suite.find_libllvm(None) == "/x/libLLVM.so.19.1"


def test_mitsuba_is_skipped_with_a_reason_when_missing(suite, monkeypatch):
    import importlib.util as iu

    real = iu.find_spec
    monkeypatch.setattr(iu, "find_spec", lambda name, *a: None if name == "mitsuba" else real(name, *a))
    assert "not installed" in suite.mitsuba_status("/x/libLLVM.so.19.1")
    monkeypatch.setattr(iu, "find_spec", real)
    if real("mitsuba") is not None:
        assert "libLLVM >= 16" in suite.mitsuba_status(None)


def test_cached_reference_prefers_an_independent_renderer_then_the_most_paths(suite, monkeypatch, tmp_path):
    """Of the cached references of a case with enough paths, a Mitsuba one (either variant)
    beats mcvar's own, and among those the largest; too small ones are not used."""
    from mcvar.interop.mitsuba import EXPORTER_VERSION

    monkeypatch.setattr(suite, "CACHE", tmp_path)
    case = suite.Case("cornell", 4, 16)
    shape = (4, 4, 3)

    def put(spp, chunks, variant, value):
        np.savez(tmp_path / f"bench-suite-ref-cornell-4-{spp}x{chunks}-{variant}-v{EXPORTER_VERSION}.npz",
                 mean=np.full(shape, value), var=np.full(shape, 1e-6))

    put(1024, 32, "mcvar", 1.0)            # the most paths, but mcvar's own
    put(64, 32, "scalar_rgb", 2.0)
    put(256, 16, "llvm_ad_rgb", 3.0)       # 4,096 spp: the largest Mitsuba one
    put(8, 2, "llvm_ad_rgb", 4.0)          # too few paths for the request below
    put(4096, 32, "llvm_ad_rgb", 6.0)
    (tmp_path / "bench-suite-ref-cornell-spheres-4-8192x32-llvm_ad_rgb-v1.npz").write_bytes(b"not this scene")
    mean, var, dof, what = suite.reference(case, 16 * 2048, None, True)
    assert mean[0, 0, 0] == 6.0 and dof == 31 and "llvm_ad_rgb, 32 x 4096 spp" in what
    (tmp_path / f"bench-suite-ref-cornell-4-4096x32-llvm_ad_rgb-v{EXPORTER_VERSION}.npz").unlink()
    mean, _, dof, what = suite.reference(case, 16 * 2048, None, True)
    assert mean[0, 0, 0] == 3.0 and dof == 15 and "16 x 256 spp" in what


def test_cases_are_chosen_by_scene_or_scene_and_size(suite):
    assert suite.select_cases(None) == suite.CASES
    assert [c.name for c in suite.select_cases("cornell-spheres")] == ["cornell-spheres 64x64, 256 spp"]
    assert len(suite.select_cases("cornell")) == 3
    assert [c.res for c in suite.select_cases("cornell-128, cornell-spheres")] == [128, 64]
    for bad in ("cornel", "cornell-32", ","):
        with pytest.raises(SystemExit, match="--cases"):
            suite.select_cases(bad)


def test_triangle_series_seeds_are_fresh_in_every_round(suite):
    seen = [int(x) for rnd in range(4) for x in suite.triangle_seeds(rnd, 3).split(",")]
    assert len(seen) == 12 and len(set(seen)) == 12
    assert suite.triangle_seeds(0, 1) == "2000"
    with pytest.raises(SystemExit, match="--triangle-seeds"):
        suite.main(["--triangle-seeds", "0", "--no-mitsuba"])


def test_block_mse_sees_correlated_pixels(suite):
    """On 2 x 2 block means, an image of independent pixels' noise has a quarter of its
    per-pixel MSE, one whose noise is shared within each block all of it (exact here:
    the noise is built so), and the reference's variance is that of its blocks' means."""
    rng = np.random.default_rng(12)
    truth = rng.random((8, 12, 3))
    noise = rng.standard_normal((8, 12, 3))
    block = rng.standard_normal((4, 6, 3)).repeat(2, axis=0).repeat(2, axis=1)
    zero = np.zeros_like(truth)
    fine = suite.mse_minus_floor(truth + noise, truth, zero)
    coarse = suite.mse_minus_floor(suite.block_means(truth + noise), suite.block_means(truth), zero[::2, ::2])
    expect = np.mean(suite.block_means(noise) ** 2)
    assert coarse == pytest.approx(expect, rel=1e-12) and coarse < fine
    assert suite.mse_minus_floor(suite.block_means(truth + block), suite.block_means(truth),
                                 zero[::2, ::2]) == pytest.approx(np.mean(block ** 2), rel=1e-12)
    var = rng.random((8, 12, 3))
    assert np.allclose(suite.block_means(None, var), var.reshape(4, 2, 6, 2, 3).sum(axis=(1, 3)) / 16)

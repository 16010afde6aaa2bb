"""Denoising as a biased but consistent estimator (mcvar.experiments.denoising)."""
import numpy as np
import pytest

from mcvar.experiments import denoise_tv, denoise_weight, denoised_target, sweep
from mcvar.experiments.denoising import photo_target


def test_schedule_shrinks_with_spp_and_validates():
    assert denoise_weight(1) == pytest.approx(0.05)
    assert denoise_weight(16) == pytest.approx(0.05 / 4)
    assert denoise_weight(100, weight_1=0.2, power=1.0) == pytest.approx(0.002)
    with pytest.raises(ValueError, match="spp"):
        denoise_weight(0)
    with pytest.raises(ValueError, match="power"):
        denoise_weight(4, power=0.0)


def test_denoise_tv_smooths_noise_and_vanishes_at_high_spp():
    rng = np.random.default_rng(3)
    flat = np.full((24, 24, 3), 0.5)
    noisy = flat * rng.gamma(4, 1 / 4, size=flat.shape)
    # the error variance falls by more than 5 standard errors of a variance
    # estimate over n values (relative error sqrt(2 / n))
    n = noisy.size
    assert np.var(denoise_tv(noisy, 4) - flat) < (1 - 5 * np.sqrt(2 / n)) * np.var(noisy - flat)
    # at a huge spp the weight is ~0: the image comes back unchanged (to ~weight)
    assert np.max(np.abs(denoise_tv(noisy, 10 ** 12) - noisy)) < 1e-4
    with pytest.raises(ValueError, match="non-negative"):
        denoise_tv(-noisy, 4)
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        denoise_tv(noisy[..., :2], 4)


def test_denoised_target_adds_methods_and_keeps_reference():
    base = photo_target("camera", res=16)
    t = denoised_target(base)
    assert t.methods == ("mc", "mc+tv") and t.key != base.key and np.array_equal(t.exact, base.exact)
    assert denoised_target(t) is t  # wrapping twice is a no-op
    with pytest.raises(TypeError, match="Target"):
        denoised_target("cornell")
    with pytest.raises(ValueError, match="skimage.data"):
        photo_target("no_such_image")


@pytest.fixture(scope="module")
def photo_sweep():
    # the sweep wraps the target by itself because a method ends with '+tv'
    return sweep(photo_target("astronaut", res=32), methods=("mc", "mc+tv"), replicates=8, seed=0,
                 workers=1, progress=False, image_metrics=True)


def test_denoiser_is_biased_but_consistent_and_wins_at_low_spp(photo_sweep):
    r = photo_sweep
    assert r.verdicts["mc"].label == "both"
    assert r.verdicts["mc+tv"].label == "consistent"  # the lecture's photon-mapping column
    plain = {m.spp: m for m in r.metrics if m.method == "mc"}
    tv = {m.spp: m for m in r.metrics if m.method == "mc+tv"}
    # lower MSE at 1 spp: one-sided z test on the jackknife errors, 5 sigma
    z = (plain[1].mse - tv[1].mse) / np.hypot(plain[1].mse_stderr, tv[1].mse_stderr)
    assert z > 5
    # the bias is detected (Sidak-corrected Welch test) where the smoothing is strongest,
    # and not at 256 spp, where the weight has shrunk 16-fold
    assert tv[1].bias_detected and not tv[256].bias_detected
    assert not any(m.bias_detected for m in plain.values())
    # SSIM and PSNR were measured and rise with spp
    assert all(np.isfinite(m.ssim) and np.isfinite(m.psnr) for m in r.metrics)
    assert plain[1].ssim < plain[256].ssim and plain[1].psnr < plain[256].psnr

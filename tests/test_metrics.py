import numpy as np
import pytest

from mcvar.metrics import loglog_fit, mse, relative_mse


def test_mse_and_relative_mse_exact_values():
    ref = np.array([1.0, 2.0, 0.0])
    est = np.array([1.5, 2.0, 0.1])
    assert mse(ref, est) == pytest.approx((0.25 + 0.01) / 3)
    assert relative_mse(ref, est, eps=0.01) == pytest.approx((0.25 / 1.01 + 0.01 / 0.01) / 3)
    with pytest.raises(ValueError, match="estimate must have the shape of reference"):
        mse(ref, est[:2])


def test_loglog_fit_recovers_exact_power_law():
    x = np.array([1, 2, 4, 8, 16, 32.0])
    fit = loglog_fit(x, 3.0 * x ** -0.5)
    assert fit.slope == pytest.approx(-0.5, abs=1e-12)
    assert np.exp(fit.intercept) == pytest.approx(3.0)
    assert fit.slope_stderr < 1e-10


def test_loglog_fit_interval_covers_true_slope_at_its_level():
    # Coverage of the 95% interval over 400 noisy fits is Binomial(400, 0.95):
    # accept anything within 4.5 binomial standard deviations.
    rng = np.random.default_rng(918273645)
    x = np.geomspace(16, 4096, 9)
    hits = 0
    R = 400
    for _ in range(R):
        y = x ** -1.0 * np.exp(rng.normal(0, 0.2, x.size))
        lo, hi = loglog_fit(x, y).slope_ci(0.95)
        hits += lo <= -1.0 <= hi
    sd = np.sqrt(R * 0.95 * 0.05)
    assert abs(hits - 0.95 * R) < 4.5 * sd


def test_weighted_fit_uses_given_sigmas():
    x = np.geomspace(1, 1000, 7)
    y = x ** -1.0
    fit = loglog_fit(x, y, sigma_log=np.full(7, 0.1))
    assert fit.slope == pytest.approx(-1.0)
    # the slope's standard error is sigma / sqrt(sum (lx - mean)^2)
    lx = np.log(x)
    assert fit.slope_stderr == pytest.approx(0.1 / np.sqrt(np.sum((lx - lx.mean()) ** 2)))


def test_loglog_fit_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        loglog_fit([1, 2], [1, 2])
    with pytest.raises(ValueError, match="positive"):
        loglog_fit([1, 2, 3], [1, 0, 3])


def test_loglog_fit_of_a_perfect_line_has_zero_slope_error_not_nan():
    fit = loglog_fit([1, 2, 4, 8], [3, 3, 3, 3])
    assert fit.slope == 0.0 and fit.slope_stderr == 0.0
    with pytest.raises(ValueError, match="distinct"):
        loglog_fit([2, 2, 2], [1, 2, 3])


def test_psnr_matches_its_definition_and_skimage():
    from skimage.metrics import peak_signal_noise_ratio as sk_psnr
    from mcvar.metrics import peak_signal_noise_ratio

    rng = np.random.default_rng(5)
    ref = rng.random((16, 16, 3))
    est = ref + 0.01 * rng.standard_normal(ref.shape)
    expected = 10 * np.log10((ref.max() - ref.min()) ** 2 / mse(ref, est))
    assert peak_signal_noise_ratio(ref, est) == pytest.approx(expected, rel=1e-12)
    assert peak_signal_noise_ratio(ref, est, data_range=1.0) == pytest.approx(
        sk_psnr(ref, est, data_range=1.0), rel=1e-12)
    assert peak_signal_noise_ratio(ref, ref) == np.inf
    with pytest.raises(ValueError, match="data_range must be a positive"):
        peak_signal_noise_ratio(ref, est, data_range=0)
    with pytest.raises(ValueError, match="reference is constant"):
        peak_signal_noise_ratio(np.ones((4, 4)), np.zeros((4, 4)))


def test_ssim_is_one_for_identity_and_falls_with_noise():
    from mcvar.metrics import structural_similarity

    rng = np.random.default_rng(6)
    y, x = np.mgrid[0:32, 0:32] / 31.0
    ref = np.stack([x, y, x * y], axis=-1)
    assert structural_similarity(ref, ref) == pytest.approx(1.0)
    noisy = [structural_similarity(ref, ref + s * rng.standard_normal(ref.shape), data_range=1.0)
             for s in (0.01, 0.1, 0.5)]
    assert 1.0 > noisy[0] > noisy[1] > noisy[2]
    with pytest.raises(ValueError, match="win_size must be odd"):
        structural_similarity(ref[:5, :5], ref[:5, :5])
    with pytest.raises(ValueError, match="must be an image"):
        structural_similarity(np.ones(4), np.ones(4), data_range=1.0)

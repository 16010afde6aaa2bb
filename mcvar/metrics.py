"""Error metrics and convergence-rate fits (layer 1).

``mse`` and ``relative_mse`` compare an image or estimate with a reference
(reference first, as in ``skimage.metrics``). Beside them, the image-quality
measures of scikit-image: :func:`peak_signal_noise_ratio` and
:func:`structural_similarity` (MSE stays the estimator-theoretic measure:
variance plus squared bias; SSIM answers 'does it look converged').
:func:`loglog_fit` fits
``log y = intercept + slope * log x`` and reports the slope's standard error,
which every rate claim in mcvar (discrepancy ~ n^-1, variance ~ N^-1, ...) is
tested against.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ._validation import as_array, check_bool, check_positive

__all__ = ["mse", "relative_mse", "peak_signal_noise_ratio", "structural_similarity", "LogLogFit",
           "loglog_fit"]


def _pair(reference, estimate):
    ref = as_array(reference, "reference")
    est = as_array(estimate, "estimate")
    if ref.shape != est.shape:
        raise ValueError(f"estimate must have the shape of reference {ref.shape}; got {est.shape}")
    if ref.size == 0:
        raise ValueError("reference must not be empty")
    return ref, est


def mse(reference, estimate) -> float:
    """Mean squared error over every element."""
    ref, est = _pair(reference, estimate)
    return float(np.mean((est - ref) ** 2))


def relative_mse(reference, estimate, *, eps: float = 1e-2) -> float:
    """Mean of ``(estimate - reference)^2 / (reference^2 + eps)``.

    The ``eps`` term keeps black reference pixels from dominating; 1e-2 is the
    common choice in the rendering literature (e.g. Rousselle et al. 2011).
    """
    ref, est = _pair(reference, estimate)
    eps = check_positive(eps, "eps")
    return float(np.mean((est - ref) ** 2 / (ref ** 2 + eps)))


def _data_range(ref: np.ndarray, data_range) -> float:
    if data_range is None:
        data_range = float(ref.max() - ref.min())
        if not data_range > 0:
            raise ValueError("reference is constant: pass data_range (e.g. 1.0 for images in [0, 1])")
        return data_range
    if isinstance(data_range, (bool, np.bool_)) or not isinstance(data_range, numbers.Real):
        raise TypeError(f"data_range must be a positive finite number; got {type(data_range).__name__} "
                        f"{data_range!r}")
    data_range = float(data_range)
    if not (np.isfinite(data_range) and data_range > 0):
        raise ValueError(f"data_range must be a positive finite number; got {data_range}")
    return data_range


def peak_signal_noise_ratio(reference, estimate, *, data_range=None) -> float:
    """Peak signal-to-noise ratio ``10 log10(data_range^2 / MSE)`` in dB.

    :func:`skimage.metrics.peak_signal_noise_ratio` with the reference first.
    ``data_range`` defaults to ``reference.max() - reference.min()`` (a
    linear-radiance render has no fixed white; pass 1.0 for sRGB images in
    [0, 1]). ``inf`` when the estimate equals the reference.
    """
    from skimage.metrics import peak_signal_noise_ratio as psnr

    ref, est = _pair(reference, estimate)
    rng = _data_range(ref, data_range)
    if np.array_equal(ref, est):
        return float("inf")
    return float(psnr(ref, est, data_range=rng))


def structural_similarity(reference, estimate, *, data_range=None, channel_axis=None,
                          win_size=None, gaussian_weights: bool = False) -> float:
    """Mean structural similarity (SSIM) of an image and its reference, in [-1, 1].

    :func:`skimage.metrics.structural_similarity` (Wang et al., "Image
    quality assessment: from error visibility to structural similarity",
    IEEE TIP 13(4), 2004) with the reference first. An ``(H, W, 3)`` or
    ``(H, W, 4)`` image is compared per channel (``channel_axis=-1`` by
    default); ``data_range`` as in :func:`peak_signal_noise_ratio`.
    ``win_size`` (odd, default 7) must not exceed the image's smaller side.
    """
    from skimage.metrics import structural_similarity as ssim

    ref, est = _pair(reference, estimate)
    check_bool(gaussian_weights, "gaussian_weights")
    if ref.ndim not in (2, 3):
        raise ValueError(f"reference must be an image (H, W) or (H, W, C); got shape {ref.shape}")
    if channel_axis is None and ref.ndim == 3:
        channel_axis = -1
    if channel_axis is not None:
        if isinstance(channel_axis, (bool, np.bool_)) or not isinstance(channel_axis, (int, np.integer)):
            raise TypeError(f"channel_axis must be None or an int; got {type(channel_axis).__name__}")
        if ref.ndim != 3 or not -3 <= channel_axis <= 2:
            raise ValueError(f"channel_axis must be an axis of a colour image (H, W, C): one of -3 .. 2 for "
                             f"reference of shape {ref.shape}" + (" (a grey image has no channel axis)"
                                                                  if ref.ndim == 2 else "") + f"; got {channel_axis}")
        channel_axis = int(channel_axis) % 3
    spatial = ref.shape if channel_axis is None else tuple(n for i, n in enumerate(ref.shape) if i != channel_axis)
    if win_size is not None and (isinstance(win_size, (bool, np.bool_))
                                 or not isinstance(win_size, (int, np.integer))):
        raise TypeError(f"win_size must be None or an odd int; got {type(win_size).__name__} {win_size!r}")
    win = 7 if win_size is None else int(win_size)
    if win < 3 or win % 2 == 0 or win > min(spatial):
        raise ValueError(f"win_size must be odd, >= 3 and <= the image's smaller side {min(spatial)}; "
                         f"got {win}")
    return float(ssim(ref, est, data_range=_data_range(ref, data_range), channel_axis=channel_axis,
                      win_size=win, gaussian_weights=gaussian_weights))


@dataclass(frozen=True)
class LogLogFit:
    """A straight-line fit in log-log space: ``y ~ exp(intercept) * x**slope``.

    Attributes
    ----------
    slope, intercept : float
        Least-squares estimates (natural logarithms).
    slope_stderr : float
        Standard error of the slope (from the residuals, or from the given
        per-point ``sigma`` when ``absolute_sigma``).
    n : int
        Number of points fitted.
    """

    slope: float
    intercept: float
    slope_stderr: float
    n: int

    def slope_ci(self, level: float = 0.95):
        """Two-sided interval for the slope (Student t with n - 2 dof)."""
        if not 0 < level < 1:
            raise ValueError(f"level must lie in (0, 1); got {level}")
        dof = max(self.n - 2, 1)
        half = stats.t.ppf(0.5 + level / 2, dof) * self.slope_stderr
        return self.slope - half, self.slope + half

    def predict(self, x):
        """Fitted ``y`` at ``x``."""
        return np.exp(self.intercept) * np.asarray(x, dtype=np.float64) ** self.slope


def loglog_fit(x, y, *, sigma_log=None) -> LogLogFit:
    """Fit ``log(y) = intercept + slope * log(x)`` by (weighted) least squares.

    Parameters
    ----------
    x, y : array_like, shape (m,)
        Positive values, ``m >= 3``.
    sigma_log : array_like, shape (m,), optional
        Known standard deviations of ``log(y)`` (e.g. the delta-method error
        ``stderr / y`` of a measured variance). With it the fit is weighted and
        the slope's standard error comes from these sigmas; without it, from
        the residual scatter.
    """
    x = as_array(x, "x", ndim=1)
    y = as_array(y, "y", ndim=1)
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same shape; got {x.shape} and {y.shape}")
    if x.size < 3:
        raise ValueError(f"x must hold at least 3 points for a fit with an error; got {x.size}")
    if not (np.all(x > 0) and np.all(y > 0)):
        raise ValueError("x and y must be positive for a log-log fit")
    lx, ly = np.log(x), np.log(y)
    if sigma_log is None:
        # ordinary least squares; the slope's error from the residual scatter
        # (0 for a perfect fit, where scipy's linregress reports NaN)
        dx = lx - lx.mean()
        sxx = float(dx @ dx)
        if not sxx > 0:
            raise ValueError("x must hold at least two distinct values")
        slope = float(dx @ (ly - ly.mean())) / sxx
        intercept = float(ly.mean() - slope * lx.mean())
        resid = ly - (intercept + slope * lx)
        stderr = float(np.sqrt(resid @ resid / (x.size - 2) / sxx))
        return LogLogFit(slope, intercept, stderr, int(x.size))
    s = as_array(sigma_log, "sigma_log", ndim=1)
    if s.shape != x.shape or not np.all(s > 0):
        raise ValueError("sigma_log must be positive with the shape of x")
    w = 1.0 / s ** 2
    design = np.stack([np.ones_like(lx), lx], axis=1)
    cov = np.linalg.inv(design.T @ (design * w[:, None]))
    beta = cov @ (design.T @ (w * ly))
    return LogLogFit(float(beta[1]), float(beta[0]), float(np.sqrt(cov[1, 1])), int(x.size))

"""Denoising as the lecture's biased-but-consistent estimator (layer 6, module 2
of :mod:`mcvar.experiments`).

A render ``I_n`` from ``n`` spp is unbiased and noisy. A denoiser ``D`` trades
that noise for bias: ``D(I_n)`` is smoother (lower variance, lower MSE at low
spp) but ``E[D(I_n)] != I`` ('Bias & Consistency' slide). If its strength
shrinks as ``n`` grows, ``D_n(I_n) -> I`` still, i.e. the denoised render is
*consistent*: the lecture's photon-mapping column (consistent, not unbiased)
reproduced with an image filter. Whether it is, is measured by the same sweep
as any other method, not assumed.

The denoiser is total-variation denoising (Chambolle 2004,
:func:`skimage.restoration.denoise_tv_chambolle`) applied to ``log(1 + L)``
(renders are high dynamic range; denoisers work on compressed values) and
mapped back with ``exp(y) - 1``. Its weight follows the schedule

    ``weight(n) = weight_1 * n ** -power``,

by default ``0.05 * n^-0.5``: the pixel noise of an n-spp render falls as
``n^-1/2``, so the smoothing falls with it and vanishes as n -> inf.

References
----------
.. [1] A. Chambolle, "An algorithm for total variation minimization and
   applications", J. Math. Imaging and Vision 20, 2004.
.. [2] L. Rudin, S. Osher, E. Fatemi, "Nonlinear total variation based noise
   removal algorithms", Physica D 60, 1992.
"""
from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np

from .._validation import as_array, check_count, check_positive
from .targets import Target

__all__ = ["DENOISE_SUFFIX", "denoise_weight", "denoise_tv", "denoised_target", "photo_target"]

#: A method named ``BASE + DENOISE_SUFFIX`` (e.g. ``'path+tv'``) is ``BASE``
#: followed by :func:`denoise_tv`.
DENOISE_SUFFIX = "+tv"
#: Default schedule: ``weight(n) = WEIGHT_1 * n ** -POWER``.
WEIGHT_1 = 0.05
POWER = 0.5


def denoise_weight(spp: int, *, weight_1: float = WEIGHT_1, power: float = POWER) -> float:
    """The TV weight used at ``spp`` samples per pixel: ``weight_1 * spp ** -power``.

    ``power > 0`` makes the weight vanish as spp grows (the condition for
    consistency).
    """
    spp = check_count(spp, "spp")
    weight_1 = check_positive(weight_1, "weight_1")
    power = check_positive(power, "power")
    return float(weight_1 * spp ** -power)


def denoise_tv(image, spp: int, *, weight_1: float = WEIGHT_1, power: float = POWER) -> np.ndarray:
    """Total-variation denoising of a linear-radiance render from ``spp`` spp.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        Linear radiance, >= 0.
    spp : int
        Samples per pixel the render used: sets the strength
        (:func:`denoise_weight`).
    weight_1, power : float
        The schedule ``weight = weight_1 * spp ** -power``.

    Returns
    -------
    ndarray, shape (H, W, 3)
        ``expm1(denoise_tv_chambolle(log1p(image), weight))``, >= 0.
    """
    from skimage.restoration import denoise_tv_chambolle

    img = as_array(image, "image", ndim=3)
    if img.shape[-1] != 3:
        raise ValueError(f"image must have shape (H, W, 3); got {img.shape}")
    if np.any(img < 0):
        raise ValueError("image must hold non-negative radiance")
    weight = denoise_weight(spp, weight_1=weight_1, power=power)
    smooth = denoise_tv_chambolle(np.log1p(img), weight=weight, channel_axis=-1)
    return np.maximum(np.expm1(smooth), 0.0)


def _denoised_evaluate(evaluate, weight_1, power, method, sampler, spp, rng):
    if method.endswith(DENOISE_SUFFIX):
        base = method[: -len(DENOISE_SUFFIX)]
        return denoise_tv(evaluate(base, sampler, spp, rng), spp, weight_1=weight_1, power=power)
    return evaluate(method, sampler, spp, rng)


def denoised_target(target: Target, *, weight_1: float = WEIGHT_1, power: float = POWER) -> Target:
    """``target`` with, for each of its methods ``m``, a method ``m + '+tv'``:
    the render of ``m`` followed by :func:`denoise_tv` at the schedule.

    The samplers, spp levels and reference settings are ``target``'s;
    methods without the suffix run unchanged, so one sweep compares a method
    with its denoised self (each from its own streams).
    :func:`mcvar.experiments.sweep` wraps the target by itself when a method
    ends with ``'+tv'``.
    """
    if not isinstance(target, Target):
        raise TypeError(f"target must be a Target; got {type(target).__name__}")
    weight_1 = check_positive(weight_1, "weight_1")
    power = check_positive(power, "power")
    tag = f";denoise=tv:{weight_1!r}:{power!r}"
    if target.key.endswith(tag):
        return target
    base = tuple(m for m in target.methods if not m.endswith(DENOISE_SUFFIX))
    return replace(target, evaluate=partial(_denoised_evaluate, target.evaluate, weight_1, power),
                   key=target.key + tag,
                   methods=base + tuple(m + DENOISE_SUFFIX for m in base))


def _photo_evaluate(truth: np.ndarray, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    if method != "mc":
        raise ValueError(f"method must be 'mc' (or 'mc+tv' through denoised_target); got {method!r}")
    # Gamma(spp, 1/spp) has mean 1 and variance 1/spp: an unbiased, non-negative
    # estimate of each pixel whose noise falls like plain Monte Carlo's (at 1 spp
    # an exponential, as heavy-tailed as a one-sample render).
    return truth * rng.gamma(spp, 1.0 / spp, size=truth.shape)


def _photo(name: str, res: int) -> np.ndarray:
    # Loaded once per target (photo_target keeps it in its evaluate): every run of a
    # sweep estimates the same image, and loading and downscaling it (an
    # anti-aliasing Gaussian over 512 x 512) costs ~50 ms, 20x the noise and the
    # denoiser. Read-only, so the target's copy stays exact.
    from skimage import data
    from skimage.transform import resize

    from ..images import srgb_to_linear

    img = getattr(data, name)()
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    small = resize(img[..., :3], (res, res), anti_aliasing=True, preserve_range=True)
    out = srgb_to_linear(np.clip(small / 255.0, 0.0, 1.0))
    out.setflags(write=False)
    return out


def photo_target(name: str = "astronaut", *, res: int = 32) -> Target:
    """A natural image from :mod:`skimage.data` estimated with Monte Carlo-like noise.

    Method ``'mc'``: each pixel of the (linear) image times an independent
    ``Gamma(spp, 1/spp)`` variable: unbiased, variance ``I^2 / spp`` (at 1 spp
    exponential, heavy-tailed like a one-sample render). The exact value is
    the image itself, so bias and consistency of a denoiser
    (:func:`denoised_target`, method ``'mc+tv'``) are measured without
    rendering. ``name``: a function of :mod:`skimage.data` returning an
    8-bit image (``'astronaut'``, ``'camera'``, ``'coffee'``, ...).
    """
    from skimage import data

    if not isinstance(name, str) or not callable(getattr(data, name, None)):
        raise ValueError(f"name must name an image of skimage.data (e.g. 'astronaut'); got {name!r}")
    res = check_count(res, "res")
    if res < 8:
        raise ValueError(f"res must be >= 8; got {res}")
    truth = _photo(name, res)          # the target owns the loaded image
    return Target(name=f"{name} (skimage.data)", evaluate=partial(_photo_evaluate, truth),
                  key=f"photo={name};res={res}", methods=("mc",), samplers=("random",),
                  spp=(1, 4, 16, 64, 256), exact=truth.copy())

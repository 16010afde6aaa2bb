"""From replicates to numbers and verdicts: per-configuration metrics, log-log
fits, bias tests and the 'Rendering Algorithm Chart' verdict per method
(layer 6, module 4 of :mod:`mcvar.experiments`)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import stats

from ..estimators import efficiency, replicate_moments
from ..metrics import LogLogFit, loglog_fit, relative_mse
from .reference import Reference


# --------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class ConfigMetrics:
    """Measurements of one configuration (method, sampler, spp) over R replicates.

    Attributes
    ----------
    variance, variance_stderr : float
        Mean over pixels (elements) of the per-pixel variance across
        replicates (ddof = 1), and its jackknife standard error.
    bias2, bias2_stderr : float
        Mean over pixels of the squared bias, corrected for the noise of the
        replicate mean and of the reference (can be slightly negative when the
        bias is 0); jackknife standard error.
    mse, mse_stderr : float
        ``variance + bias2``: the mean squared error against the truth.
    rel_mse : float
        Relative MSE (:func:`mcvar.metrics.relative_mse`, eps = 1e-2), averaged
        over replicates, minus the reference's own contribution.
    seconds : float
        Mean wall time of one run (one estimate / image).
    efficiency : float
        ``1 / (mse * seconds)`` (:func:`mcvar.estimators.efficiency`, the
        one definition; ``inf`` when the measured MSE is <= 0).
    bias, bias_stderr, bias_z, bias_dof, bias_pvalue : float
        Bias of the element-mean (mean image value minus the reference's), its
        standard error, Welch t statistic, degrees of freedom and two-sided
        p-value.
    bias_detected : bool
        ``bias_pvalue < alpha_family`` (Sidak-corrected over the method's
        configurations; see :func:`sweep`).
    rounding : float
        Floating-point floor of the bias test's standard error,
        ``64 eps |value|``: an error below it is rounding, not bias or noise.
    deterministic : bool
        True when neither the replicates nor the reference scatter (every
        replicate's mean value identical, the reference exact): the estimator
        has zero variance, its bias is the error itself, measured exactly, and
        ``bias_z`` only divides it by the rounding floor (a fixed grid's bias
        of 2/m^2 gives |t| ~ 1e13: certain, but not a statistic to print).
        Verdict evidence and reports then say 'bias = X exactly'.
    psnr, ssim : float
        Mean over replicates of :func:`mcvar.metrics.peak_signal_noise_ratio`
        and :func:`mcvar.metrics.structural_similarity` of the image against
        the reference, both as displayed (sRGB-encoded, clipped to [0, 1],
        data range 1); NaN unless the sweep ran with ``image_metrics=True``
        on an image target.
    """

    method: str
    sampler: str
    spp: int
    replicates: int
    variance: float
    variance_stderr: float
    bias2: float
    bias2_stderr: float
    mse: float
    mse_stderr: float
    rel_mse: float
    seconds: float
    efficiency: float
    bias: float
    bias_stderr: float
    bias_z: float
    bias_dof: float
    bias_pvalue: float
    bias_detected: bool = False
    rounding: float = 0.0
    deterministic: bool = False
    psnr: float = float("nan")
    ssim: float = float("nan")

    @property
    def figure_of_merit(self) -> float:
        """``MSE x time`` (seconds): lower is better; ``1 / efficiency``."""
        return max(self.mse, 0.0) * self.seconds


def _image_quality(values: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """Mean PSNR and SSIM over replicates ``values`` (R, H, W, C), as displayed."""
    from ..images import linear_to_srgb
    from ..metrics import peak_signal_noise_ratio, structural_similarity

    side = min(ref.shape[:2])
    win = min(7, side if side % 2 else side - 1)
    show = lambda img: np.clip(linear_to_srgb(np.clip(img, 0.0, None)), 0.0, 1.0)  # noqa: E731
    r = show(ref)
    psnr = [peak_signal_noise_ratio(r, show(v), data_range=1.0) for v in values]
    ssim = [structural_similarity(r, show(v), data_range=1.0, win_size=win) if win >= 3 else np.nan
            for v in values]
    return float(np.mean(psnr)), float(np.mean(ssim))


def _moments(x, ref, ref_var):
    """variance, bias2, mse of replicates ``x`` (R, P) against ``ref``."""
    return replicate_moments(x, ref, ref_var)


def _config_metrics(method, sampler, spp, values, seconds, ref: Reference) -> ConfigMetrics:
    r = values.shape[0]
    x = values.reshape(r, -1)
    ref_v = ref.value.reshape(-1)
    ref_var = ref.variance.reshape(-1)
    variance, bias2, mse = _moments(x, ref_v, ref_var)
    jack = np.array([_moments(np.delete(x, i, axis=0), ref_v, ref_var) for i in range(r)])
    stderr = np.sqrt((r - 1) / r * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
    eps = 1e-2
    rel = float(np.mean([relative_mse(ref_v, xi, eps=eps) for xi in x])
                - np.mean(ref_var / (ref_v ** 2 + eps)))
    sec = float(np.mean(seconds))
    eff = efficiency(mse, sec)
    # Welch t test of the element-mean against the reference's element-mean.
    t_r = x.mean(axis=1)
    a = t_r.var(ddof=1) / r
    bvar = ref.mean_variance
    diff = float(t_r.mean() - ref_v.mean())
    # A float64 mean carries rounding of order eps * |value|. Without this floor
    # an exact, zero-variance estimator (importance sampling with the integrand
    # as its pdf) would be 'biased' at z = inf by its last bit; a real bias of a
    # zero-variance estimator (the fixed grid's 2 / m^2) still stands out.
    rounding = 64.0 * np.finfo(np.float64).eps * max(abs(float(t_r.mean())), abs(float(ref_v.mean())))
    se = np.sqrt(a + bvar + rounding ** 2)
    if se > 0:
        z = diff / se
        den = a * a / (r - 1) + (bvar * bvar / (ref.chunks - 1) if ref.chunks > 1 else 0.0)
        dof = float((a + bvar) ** 2 / den) if den > 0 else float("inf")
        p = float(2 * stats.t.sf(abs(z), dof))
    else:  # no scatter at all: any difference is certain
        z = 0.0 if diff == 0 else float(np.copysign(np.inf, diff))
        dof, p = float("inf"), (1.0 if diff == 0 else 0.0)
    return ConfigMetrics(method, sampler, int(spp), r, variance, float(stderr[0]), bias2,
                         float(stderr[1]), mse, float(stderr[2]), rel, sec, eff, diff, float(se),
                         float(z), dof, p, rounding=float(rounding),
                         deterministic=bool(a == 0.0 and bvar == 0.0))


# --------------------------------------------------------------------------
# Fits and verdicts
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class MethodFits:
    """Log-log convergence fits of one (method, sampler) over its spp levels.

    Each is a :class:`mcvar.metrics.LogLogFit` (slope and its standard error)
    or None when fewer than 3 levels have a positive value.
    """

    method: str
    sampler: str
    variance: LogLogFit | None
    mse: LogLogFit | None
    mse_time: LogLogFit | None
    bias2: LogLogFit | None
    consistent: bool
    evidence: str


@dataclass(frozen=True)
class Verdict:
    """The measured answer to the 'Rendering Algorithm Chart' for one method.

    ``label`` is ``'both'`` (unbiased and consistent), ``'unbiased'``,
    ``'consistent'`` or ``'neither'``; ``evidence`` says which measurements
    decided it.
    """

    method: str
    unbiased: bool
    consistent: bool
    label: str
    evidence: str


def _fit(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = np.isfinite(y) & (y > 0)
    if keep.sum() < 3:
        return None
    fit = loglog_fit(x[keep], y[keep])
    if not np.isfinite(fit.slope_stderr):  # points exactly on a flat line: no residual
        fit = LogLogFit(fit.slope, fit.intercept, 0.0, fit.n)
    return fit


def _decreases(first: ConfigMetrics, last: ConfigMetrics, name: str, alpha: float) -> bool:
    """One-sided z test that ``name`` (mse or bias2) is lower at ``last`` than at
    ``first``, with their jackknife standard errors (independent replicates)."""
    a, b = getattr(first, name), getattr(last, name)
    s = float(np.hypot(getattr(first, f"{name}_stderr"), getattr(last, f"{name}_stderr")))
    if s == 0:
        return bool(a > b)
    return bool(a - b > stats.norm.ppf(1 - alpha) * s)


def _fits(method, sampler, rows: Sequence[ConfigMetrics], alpha: float) -> MethodFits:
    spp = [m.spp for m in rows]
    mse = [m.mse for m in rows]
    f_var = _fit(spp, [m.variance for m in rows])
    f_mse = _fit(spp, mse)
    f_time = _fit([m.seconds for m in rows], mse)
    f_b2 = _fit(spp, [m.bias2 for m in rows])
    first, last = rows[0], rows[-1]
    if all(abs(m.mse) <= m.rounding ** 2 for m in rows):
        return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, True,
                          "exact at every level (error within floating-point rounding)")
    if len(rows) < 2:
        return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, False,
                          "one spp level: consistency cannot be measured")
    # The MSE falls if its log-log slope is negative by a one-sided t test over
    # every level (needs >= 4 levels for power), or if the last level's MSE is
    # below the first's by a z test: with a handful of replicates the first
    # level's MSE is too noisy for the z test alone (a scalar integrand's MSE
    # at 1 sample from 8 replicates has a relative error of ~0.5).
    slope_falls = bool(f_mse is not None and f_mse.n >= 4 and f_mse.slope_stderr > 0
                       and f_mse.slope / f_mse.slope_stderr < -stats.t.ppf(1 - alpha, f_mse.n - 2))
    mse_falls = slope_falls or _decreases(first, last, "mse", alpha)
    bias_falls = _decreases(first, last, "bias2", alpha)
    bias_gone = (not last.bias_detected) or bias_falls
    words = [f"MSE {first.mse:.3g} at {first.spp} -> {last.mse:.3g} at {last.spp} spp "
             f"({'falls' if mse_falls else 'does not fall'} significantly"
             + (f"; slope {f_mse.slope:.2f} ± {f_mse.slope_stderr:.2f})" if f_mse else ")"),
             f"bias at {last.spp} spp " + _bias_words(last)]
    if last.bias_detected:
        words.append(f"bias² {first.bias2:.3g} -> {last.bias2:.3g} "
                     f"({'falls' if bias_falls else 'does not fall'} significantly)")
    return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, bool(mse_falls and bias_gone),
                      "; ".join(words))


def _exact_bias(m: ConfigMetrics) -> str:
    """The bias of a zero-variance configuration (its error): '+0.002081' or '0 (to rounding)'."""
    return "0 (to rounding)" if abs(m.bias) <= m.rounding else f"{m.bias:+.4g}"


def _bias_words(m: ConfigMetrics) -> str:
    """'detected (t = ...)' / 'not detected (t = ...)', or the exact bias when deterministic."""
    if m.deterministic:
        return f"= {_exact_bias(m)} exactly (zero variance, deterministic)"
    return f"{'detected' if m.bias_detected else 'not detected'} (t = {m.bias_z:.1f})"


def _verdicts(methods, metrics, fits, alpha_family) -> dict:
    out = {}
    for method in methods:
        rows = [m for m in metrics if m.method == method]
        mfits = [f for f in fits.values() if f.method == method]
        detected = [m for m in rows if m.bias_detected]
        unbiased = not detected
        consistent = all(f.consistent for f in mfits)
        label = {(True, True): "both", (True, False): "unbiased",
                 (False, True): "consistent", (False, False): "neither"}[(unbiased, consistent)]
        noisy = [m for m in rows if not m.deterministic]
        exact = [m for m in rows if m.deterministic]
        ev = []
        if noisy:
            worst = max(noisy, key=lambda m: abs(m.bias_z))
            ev.append(f"bias test: {sum(m.bias_detected for m in noisy)} of {len(noisy)} configurations "
                      f"reject zero bias at Sidak-corrected p < {alpha_family:.2g} (largest |t| = "
                      f"{abs(worst.bias_z):.1f} at {worst.sampler}, {worst.spp} spp)")
        if exact:
            nonzero = sum(abs(m.bias) > m.rounding for m in exact)
            ev.append(f"zero variance in {len(exact)} of {len(rows)} configurations (deterministic: "
                      f"identical replicates, so no t statistic), bias nonzero beyond rounding in {nonzero}: "
                      "bias = " + ", ".join(f"{_exact_bias(m)} ({m.sampler}, {m.spp} spp)" for m in exact)
                      + " exactly")
        ev += [f"{f.sampler}: {'consistent' if f.consistent else 'not consistent'} ({f.evidence})"
               for f in mfits]
        out[method] = Verdict(method, unbiased, consistent, label, "; ".join(ev))
    return out



def _with_detection(m: ConfigMetrics, alpha_family: float) -> ConfigMetrics:
    return replace(m, bias_detected=bool(m.bias_pvalue < alpha_family))


# --------------------------------------------------------------------------
# Block bias test: power against spatially structured bias
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class BlockBias:
    """Result of :func:`block_bias_test` for one configuration.

    Attributes
    ----------
    blocks : int
        Blocks tested (blocks with no kept pixel are dropped).
    chi2 : float
        ``sum_b z_b^2`` of the blocks' Welch statistics mapped to standard
        normal deviates (``chi2(blocks)`` under zero bias).
    pvalue_chi2 : float
        ``P(chi2(blocks) > chi2)``.
    max_z : float
        Largest ``|z_b|``.
    pvalue_max : float
        Sidak-corrected p-value of the largest ``|z_b|`` over the blocks.
    pvalue : float
        The test's p-value: ``min(1, 2 min(pvalue_chi2, pvalue_max))``
        (Bonferroni over its two statistics).
    worst : tuple of int
        ``(row, col)`` of the first pixel of the block with the largest ``|z_b|``.
    z : ndarray, shape (rows, cols)
        Per-block ``z_b`` (NaN where a block was dropped).
    """

    blocks: int
    chi2: float
    pvalue_chi2: float
    max_z: float
    pvalue_max: float
    pvalue: float
    worst: tuple
    z: np.ndarray = None


def block_bias_test(values, ref_value, ref_variance, ref_chunks: int, *, block: int = 4,
                    mask=None) -> BlockBias:
    """Test zero bias of image replicates per block of pixels, against a reference.

    A bias that moves light around (the blur of a density estimate, the flat
    patches of a radiosity mesh) cancels in the image mean, so the mean's t
    test has no power against it. Per ``block x block`` block ``b``, the mean
    over its kept pixels and channels of each replicate, ``Y_rb``, is compared
    with the reference's, ``y_b``, by Welch's t test [1]_:

    ``t_b = (mean_r Y_rb - y_b) / sqrt(s_b^2 / R + v_b)``, with ``s_b^2`` the
    sample variance of ``Y_rb`` over the R replicates and ``v_b`` the
    reference block mean's variance; Welch-Satterthwaite degrees of freedom
    with ``R - 1`` degrees of freedom for the replicates' term and, for the
    reference's, Welch-Satterthwaite's over its pixels (each pixel's variance
    has ``ref_chunks - 1``). Each ``t_b`` is
    mapped to the standard normal deviate of the same two-sided p-value,
    ``z_b^2 = F^{-1}_{chi2(1)}(1 - p_b)``. Under zero bias, with blocks
    independent (a camera tracer's pixels are), the ``z_b`` are independent
    standard normal, so

    * ``sum_b z_b^2 ~ chi2(B)``: power against many small biases (blur spreads
      a bias over many blocks), and
    * ``max_b |z_b|`` with the Sidak correction ``1 - (1 - p_min)^B``: power
      against one large local bias (a corner, a light leak), and valid under
      any positive dependence of the blocks (Sidak 1967) [2]_.

    The returned ``pvalue`` takes the smaller of the two, Bonferroni-corrected
    (times 2), so it holds its level whichever of them rejects.

    Parameters
    ----------
    values : array_like, shape (R, H, W) or (R, H, W, C)
        R >= 3 independent replicate images.
    ref_value, ref_variance : array_like, shape (H, W) or (H, W, C)
        The reference image and the variance of its per-pixel value
        (:class:`~mcvar.experiments.reference.Reference`), pixels independent.
    ref_chunks : int
        Independent chunks behind the reference (its variance's degrees of
        freedom plus one); 0 or 1 for an exact reference (``v_b`` taken as 0).
    block : int
        Block side in pixels (edge blocks may be smaller).
    mask : array_like of bool, shape (H, W), optional
        Pixels to test (True). Exclude pixels that see an emitter directly:
        their variance is huge and their replicate distribution far from
        normal at a few samples per pixel.

    Returns
    -------
    BlockBias

    Notes
    -----
    The reference's block variance: channels of one pixel share their paths,
    so the variance of a pixel's channel mean is bounded by the square of
    the mean of the channels' standard deviations (Cauchy-Schwarz), which is
    used (conservative); pixels add independently.

    References
    ----------
    .. [1] B. L. Welch, "The generalization of 'Student's' problem when several
       different population variances are involved", Biometrika 34, 1947.
    .. [2] Z. Sidak, "Rectangular confidence regions for the means of
       multivariate normal distributions", JASA 62(318), 1967.
    """
    x = np.asarray(values, dtype=np.float64)
    ref = np.asarray(ref_value, dtype=np.float64)
    rvar = np.asarray(ref_variance, dtype=np.float64)
    if x.ndim not in (3, 4) or x.shape[1:] != ref.shape:
        raise ValueError(f"values must have shape (R, H, W[, C]) matching ref_value {ref.shape}; got {x.shape}")
    if rvar.shape != ref.shape:
        raise ValueError(f"ref_variance must have ref_value's shape {ref.shape}; got {rvar.shape}")
    r = x.shape[0]
    if r < 3:
        raise ValueError(f"values must hold >= 3 replicates; got {r}")
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block < 1:
        raise ValueError(f"block must be a positive integer; got {block!r}")
    if isinstance(ref_chunks, bool) or not isinstance(ref_chunks, (int, np.integer)) or ref_chunks < 0:
        raise ValueError(f"ref_chunks must be a non-negative integer; got {ref_chunks!r}")
    if x.ndim == 3:
        x, ref, rvar = x[..., None], ref[..., None], rvar[..., None]
    h, w = ref.shape[:2]
    keep = np.ones((h, w), bool) if mask is None else np.asarray(mask, dtype=bool)
    if keep.shape != (h, w):
        raise ValueError(f"mask must have shape {(h, w)}; got {keep.shape}")
    if not keep.any():
        raise ValueError("mask must keep at least one pixel (True); it keeps none")
    # per pixel: channel mean, and the (upper bound of the) variance of the reference's channel mean
    px = x.mean(axis=3) * keep
    pref = ref.mean(axis=2) * keep
    pvar = np.sqrt(rvar).mean(axis=2) ** 2 * keep
    nb_r, nb_c = -(-h // block), -(-w // block)
    ends_r, ends_c = np.arange(0, h, block), np.arange(0, w, block)

    def blocksum(a):  # sum over each block of the last two axes
        return np.add.reduceat(np.add.reduceat(a, ends_r, axis=-2), ends_c, axis=-1)

    count = blocksum(keep.astype(np.float64))
    valid = count > 0
    n = np.where(valid, count, 1.0)
    y = blocksum(px) / n                                  # (R, nb_r, nb_c)
    yref = blocksum(pref) / n
    vref = blocksum(pvar) / n ** 2 if ref_chunks > 1 else np.zeros_like(yref)
    a = y.var(axis=0, ddof=1) / r
    d = y.mean(axis=0) - yref
    # rounding floor, as in the mean's test: an exact estimator is not 'biased' by its last bit
    rounding = 64.0 * np.finfo(np.float64).eps * np.maximum(np.abs(y.mean(axis=0)), np.abs(yref))
    se2 = a + vref + rounding ** 2
    # Welch-Satterthwaite: the reference block variance sums its pixels' variances, each with
    # ref_chunks - 1 degrees of freedom, so its own are (sum v_p)^2 / sum (v_p^2 / (chunks - 1))
    # and its term of the denominator is vref^2 / dof_ref = sum_p (v_p / n)^2 / (chunks - 1)
    den = a * a / (r - 1) + (blocksum(pvar ** 2) / n ** 4 / (ref_chunks - 1) if ref_chunks > 1 else 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(den > 0, (a + vref) ** 2 / np.where(den > 0, den, 1.0), np.inf)
        t = np.where(se2 > 0, d / np.sqrt(np.where(se2 > 0, se2, 1.0)), np.where(d == 0, 0.0, np.inf))
    p = 2.0 * stats.t.sf(np.abs(t), dof)
    z = np.sign(t) * np.sqrt(stats.chi2.isf(p, 1))
    z = np.where(valid, z, np.nan)
    nblocks = int(valid.sum())
    z2 = np.minimum(z[valid] ** 2, 1e300)
    chi2 = float(z2.sum())
    p_chi2 = float(stats.chi2.sf(chi2, nblocks))
    p_min = float(p[valid].min())
    p_max = float(-np.expm1(nblocks * np.log1p(-p_min))) if p_min < 1 else 1.0
    worst = np.unravel_index(np.nanargmax(np.abs(z)), z.shape)
    return BlockBias(nblocks, chi2, p_chi2, float(np.abs(z[valid]).max()), p_max,
                     float(min(1.0, 2.0 * min(p_chi2, p_max))),
                     (int(worst[0] * block), int(worst[1] * block)), z)


def image_bias_verdict(values: dict, metrics: Sequence[ConfigMetrics], ref: Reference, *,
                       alpha: float = 1e-3, block: int = 4, mask=None) -> tuple[bool, str, dict]:
    """Unbiased? of one method's image replicates at several levels: the mean's
    Welch test and :func:`block_bias_test` at every level.

    Parameters
    ----------
    values : dict
        ``level -> (R, H, W[, C])`` replicates of one method (one sampler).
    metrics : sequence of ConfigMetrics
        The same configurations' metrics (their ``bias_pvalue``, the image
        mean's test), one per level.
    ref : Reference
    alpha : float
        Family-wise significance over the method's ``2 L`` tests (the mean's
        and the blocks' at each of L levels), Sidak-corrected: each test
        rejects at ``1 - (1 - alpha)^(1 / 2L)``.
    block, mask
        As in :func:`block_bias_test`.

    Returns
    -------
    unbiased : bool
        No test rejects.
    evidence : str
        One line: the smallest p-values and where.
    blocks : dict
        ``level -> BlockBias``.
    """
    levels = sorted(values)
    per_test = 1.0 - (1.0 - alpha) ** (1.0 / (2 * len(levels)))
    tests = {n: block_bias_test(values[n], ref.value, ref.variance, ref.chunks, block=block, mask=mask)
             for n in levels}
    mean_p = {m.spp: m.bias_pvalue for m in metrics}
    mean_hits = [n for n in levels if mean_p.get(n, 1.0) < per_test]
    block_hits = [n for n in levels if tests[n].pvalue < per_test]
    worst = min(levels, key=lambda n: tests[n].pvalue)
    w = tests[worst]
    evidence = (f"block test ({block}x{block} pixel blocks, emitter pixels excluded): {len(block_hits)} of "
                f"{len(levels)} levels reject zero bias at Sidak-corrected p < {per_test:.2g} (smallest p = "
                f"{w.pvalue:.2g} at level {worst}: chi2 = {w.chi2:.0f} over {w.blocks} blocks, largest |z| = "
                f"{w.max_z:.1f} at pixel {w.worst}); image-mean test rejects at {len(mean_hits)} of {len(levels)}")
    return not (mean_hits or block_hits), evidence, tests

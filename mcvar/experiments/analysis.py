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

    @property
    def figure_of_merit(self) -> float:
        """``MSE x time`` (seconds): lower is better; ``1 / efficiency``."""
        return max(self.mse, 0.0) * self.seconds


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
                         float(z), dof, p, rounding=float(rounding))


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
             f"bias at {last.spp} spp {'detected' if last.bias_detected else 'not detected'} "
             f"(t = {last.bias_z:.1f})"]
    if last.bias_detected:
        words.append(f"bias² {first.bias2:.3g} -> {last.bias2:.3g} "
                     f"({'falls' if bias_falls else 'does not fall'} significantly)")
    return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, bool(mse_falls and bias_gone),
                      "; ".join(words))


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
        worst = max(rows, key=lambda m: abs(m.bias_z))
        ev = [f"bias test: {len(detected)} of {len(rows)} configurations reject zero bias at "
              f"Sidak-corrected p < {alpha_family:.2g} (largest |t| = {abs(worst.bias_z):.1f} at "
              f"{worst.sampler}, {worst.spp} spp)"]
        ev += [f"{f.sampler}: {'consistent' if f.consistent else 'not consistent'} ({f.evidence})"
               for f in mfits]
        out[method] = Verdict(method, unbiased, consistent, label, "; ".join(ev))
    return out



def _with_detection(m: ConfigMetrics, alpha_family: float) -> ConfigMetrics:
    return replace(m, bias_detected=bool(m.bias_pvalue < alpha_family))

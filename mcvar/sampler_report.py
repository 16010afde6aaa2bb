"""The samplers report: points, spectra and discrepancy versus n (layer 7).

``mcvar samplers --n 256 --out DIR`` calls :func:`write_samplers_report`, which
writes

* ``points.png``: every sampler's n points side by side;
* ``spectra.png``: every sampler's periodogram (mean of several realizations)
  and ``radial_spectra.png``: the radially averaged power, with anisotropy;
* ``discrepancy.png``: star discrepancy versus n (log-log), one panel per
  sampler, with the fitted slope and its standard error and the expected rate;
* ``discrepancy.csv`` (every n: star and L2-star means and standard errors),
  ``slopes.csv`` (fitted and expected slopes) and ``spectra.csv``
  (low-frequency power and anisotropy).
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
from matplotlib.ticker import NullFormatter
from tqdm.auto import tqdm

from . import discrepancy as disc
from ._validation import check_count
from .metrics import loglog_fit
from .pages import write_csv
from .plotting import plot_loglog, plt, save_figure
from .samplers import SAMPLERS

__all__ = ["discrepancy_sweep", "write_samplers_report"]

# Each sampler's expected star-discrepancy slope, whether it needs square counts and
# whether it is randomized are fields of its record (mcvar.samplers.Sampler).

_FIT_FROM = 64  # fit slopes on n >= 64, as the issue asks (small n is pre-asymptotic)


def _points(name: str, n: int, rng) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # sobol at n != 2^m: shown in the title instead
        return SAMPLERS[name](n, rng=rng)


def _usable_n(name: str, n: int) -> int:
    """n itself, or the largest perfect square <= n for samplers that need one."""
    return math.isqrt(n) ** 2 if SAMPLERS[name].square else n


def _root(rng, seed, where: str) -> np.random.SeedSequence:
    """The report's root SeedSequence from ``rng`` (None: 0, an int, a SeedSequence or a
    Generator's own sequence); ``seed`` is the deprecated alias of ``rng``."""
    if seed is not None:
        if rng is not None:
            raise TypeError(f"{where} got both rng= and its deprecated alias seed=; pass rng= only")
        warnings.warn(f"{where}(seed=...) is deprecated: pass rng=", DeprecationWarning, stacklevel=3)
        rng = seed
    if isinstance(rng, np.random.SeedSequence):
        return rng
    if isinstance(rng, np.random.Generator):
        return rng.bit_generator.seed_seq
    return np.random.SeedSequence(check_count(0 if rng is None else rng, "rng", allow_zero=True))


def discrepancy_sweep(n_values, *, names=None, replicates: int = 4, rng=None,
                      progress: bool = False, seed=None) -> list[dict]:
    """Star and L2-star discrepancy of every sampler at every n.

    Parameters
    ----------
    n_values : sequence of int
        Point counts; samplers that need a perfect square (grid, jittered)
        skip the others.
    names : sequence of str, optional
        Sampler names (default: all of :data:`mcvar.samplers.SAMPLERS`).
    replicates : int
        Independent realizations per n for randomized samplers (deterministic
        ones are computed once).
    rng : None, int, SeedSequence or Generator
        Root of the independent streams (one spawned per sampler, n and
        replicate); None: 0. ``seed=`` is its deprecated alias.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    list of dict
        One row per (sampler, n): ``sampler, n, replicates, star, star_se,
        l2_star, l2_star_se`` (means over replicates and their standard errors,
        0 for one replicate).
    """
    names = list(SAMPLERS) if names is None else list(names)
    for name in names:
        if name not in SAMPLERS:
            raise ValueError(f"names must hold sampler names {tuple(SAMPLERS)}; got {name!r}")
    reps = check_count(replicates, "replicates")
    ns = sorted({check_count(int(n), "n_values") for n in n_values})
    root = _root(rng, seed, "discrepancy_sweep")
    tasks = []
    for name, stream in zip(names, root.spawn(len(names))):
        r = 1 if SAMPLERS[name].deterministic else reps
        sizes = [n for n in ns if _usable_n(name, n) == n]
        for n, sub in zip(sizes, stream.spawn(len(sizes))):
            tasks.append((name, n, sub.spawn(r)))
    total = sum(len(t[2]) for t in tasks)
    rows = []
    with tqdm(total=total, desc="discrepancy", unit="set", disable=not progress, leave=False) as bar:
        for name, n, streams in tasks:
            star, l2 = [], []
            for s in streams:
                pts = _points(name, n, np.random.default_rng(s))
                star.append(disc.star(pts))
                l2.append(disc.l2_star(pts))
                bar.update(1)
            k = len(streams)
            se = (lambda v: float(np.std(v, ddof=1) / math.sqrt(k)) if k > 1 else 0.0)
            rows.append({"sampler": name, "n": n, "replicates": k,
                         "star": float(np.mean(star)), "star_se": se(star),
                         "l2_star": float(np.mean(l2)), "l2_star_se": se(l2)})
    return rows


def _fit_rows(rows: list[dict]):
    n = np.array([r["n"] for r in rows], dtype=float)
    keep = n >= _FIT_FROM
    if keep.sum() < 3:
        keep = np.ones_like(keep)
    return keep if keep.sum() >= 3 else None


def _grid_axes(count: int, size: float = 2.6):
    cols = 3
    rows = int(math.ceil(count / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(cols * size, rows * size), squeeze=False)
    for ax in axes.flat[count:]:
        ax.set_visible(False)
    return fig, axes.flat


def write_samplers_report(out, *, n: int = 256, n_max: int = 4096, rng=None,
                          progress: bool = True, seed=None) -> dict[str, Path]:
    """Write the samplers report (figures and CSVs) into the folder ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (created).
    n : int
        Points per sampler in the scatter plots and spectra (>= 4); grid and
        jittered use the largest perfect square <= n.
    n_max : int
        Largest n of the discrepancy sweep n = 16, 32, ..., n_max (powers of
        2; >= 16). Slopes are fitted on n >= 64.
    rng : None, int, SeedSequence or Generator
        Root seed (None: 0); the same seed gives the same numbers. ``seed=``
        is its deprecated alias.
    progress : bool
        Show progress bars.

    Returns
    -------
    dict of str to Path
        ``points``, ``spectra``, ``radial_spectra``, ``discrepancy`` (PNG),
        ``discrepancy_csv``, ``slopes_csv``, ``spectra_csv``.

    Notes
    -----
    Randomized samplers are averaged over 4 realizations per n (discrepancy)
    and 8 (spectra). The default run (n = 256, n_max = 4096) takes about
    30 s on one core, dominated by the exact star discrepancy at n = 4096.

    Examples
    --------
    >>> paths = write_samplers_report("out/samplers", n=64, n_max=256,
    ...                               progress=False)  # doctest: +SKIP
    """
    n = check_count(n, "n")
    if n < 4:
        raise ValueError(f"n must be >= 4 (a 2 x 2 grid at least); got {n}")
    n_max = check_count(n_max, "n_max")
    if n_max < 16:
        raise ValueError(f"n_max must be >= 16; got {n_max}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    root = _root(rng, seed, "write_samplers_report")
    points_seed, spectra_seed, sweep_seed = root.spawn(3)
    names = list(SAMPLERS)
    paths: dict[str, Path] = {}

    # --- points side by side
    fig, axes = _grid_axes(len(names))
    for ax, name, s in zip(axes, names, points_seed.spawn(len(names))):
        m = _usable_n(name, n)
        pts = _points(name, m, np.random.default_rng(s))
        ax.scatter(pts[:, 0], pts[:, 1], s=4, color="k")
        ax.set(xlim=(0, 1), ylim=(0, 1), xticks=[], yticks=[], aspect="equal")
        ax.set_title(f"{name} (n={m})\nD*={disc.star(pts):.4f}", fontsize=9)
    paths["points"] = save_figure(fig, out / "points.png")

    # --- spectra: mean periodogram over realizations, radial power, anisotropy
    spectra_rows, radial = [], {}
    fig, axes = _grid_axes(len(names))
    cutoff = 0.5 * math.sqrt(n)
    for ax, name, s in tqdm(list(zip(axes, names, spectra_seed.spawn(len(names)))), desc="spectra",
                            disable=not progress, leave=False):
        m = _usable_n(name, n)
        reps = 1 if SAMPLERS[name].deterministic else 8
        spectra = [disc.power_spectrum(_points(name, m, np.random.default_rng(g))) for g in s.spawn(reps)]
        power = np.mean([p.power for p in spectra], axis=0)
        centre = power.shape[0] // 2
        power[centre, centre] = np.nan  # the DC term (= n) would swamp the colour scale
        kmax = spectra[0].frequencies[-1]
        ax.imshow(np.log10(np.maximum(power.T, 1e-3)), origin="lower", cmap="magma", vmin=-2, vmax=1.5,
                  extent=(-kmax - 0.5, kmax + 0.5, -kmax - 0.5, kmax + 0.5))
        ax.set(xticks=[], yticks=[])
        low = float(np.mean([p.low_frequency_power(cutoff) for p in spectra]))
        aniso = float(np.mean([p.anisotropy for p in spectra]))
        ax.set_title(f"{name}\nlow-freq {low:.2f}, aniso {aniso:.2f}", fontsize=9)
        radial[name] = (spectra[0].radial_frequency, np.mean([p.radial_power for p in spectra], axis=0))
        spectra_rows.append({"sampler": name, "n": m, "realizations": reps,
                             "low_frequency_power": low, "cutoff": cutoff, "anisotropy": aniso})
    fig.suptitle(f"log10 periodogram |S(k)|^2 / n, k in [-{kmax}, {kmax}]^2 (DC removed)", fontsize=10)
    paths["spectra"] = save_figure(fig, out / "spectra.png")

    fig, ax = plt.subplots(figsize=(7, 4))
    for name, (freq, pw) in radial.items():
        ax.plot(freq / math.sqrt(n), pw, label=name, lw=1)
    ax.axhline(1.0, color="gray", lw=0.8, ls=":")
    ax.set(yscale="log", xlabel="|k| / sqrt(n)", ylabel="radially averaged power",
           title="Radial power: random is flat (1), blue noise dark below its ring")
    ax.legend(fontsize=7, ncol=3)
    paths["radial_spectra"] = save_figure(fig, out / "radial_spectra.png")

    # --- discrepancy versus n
    ns = [2 ** k for k in range(4, int(math.log2(n_max)) + 1)]
    rows = discrepancy_sweep(ns, names=names, replicates=4, rng=sweep_seed, progress=progress)
    slopes = []
    fig, axes = _grid_axes(len(names), size=3.3)
    for ax, name in zip(axes, names):
        mine = [r for r in rows if r["sampler"] == name]
        x = np.array([r["n"] for r in mine], dtype=float)
        y = np.array([r["star"] for r in mine])
        err = np.array([r["star_se"] for r in mine])
        keep = _fit_rows(mine)
        fit = None
        if keep is not None:
            fit = plot_loglog(ax, x[keep], y[keep], label="D*", yerr=err[keep])
            ax.plot(x[~keep], y[~keep], "o", mfc="none", ms=3, color="gray")
        expected, why = SAMPLERS[name].star_slope, SAMPLERS[name].star_slope_why
        a = int(np.argmax(keep)) if keep is not None else 0  # anchor at the first fitted n
        ax.plot(x, y[a] * (x / x[a]) ** expected, ls=":", color="gray", label=f"n^{expected:g}")
        l2fit = loglog_fit(x[keep], np.array([r["l2_star"] for r in mine])[keep]) if keep is not None else None
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_title(name, fontsize=9)
        ax.legend(fontsize=6)
        for measure, f in (("star", fit), ("l2_star", l2fit)):
            slopes.append({"sampler": name, "measure": measure,
                           "slope": f.slope if f else float("nan"),
                           "slope_stderr": f.slope_stderr if f else float("nan"),
                           "expected_star_slope": expected, "why": why,
                           "n_from": int(x[keep].min()) if keep is not None else 0,
                           "n_to": int(x[keep].max()) if keep is not None else 0})
    fig.suptitle("Star discrepancy vs n (dashed: fit on n >= 64; dotted: expected rate)", fontsize=10)
    fig.tight_layout()
    paths["discrepancy"] = save_figure(fig, out / "discrepancy.png")

    paths["discrepancy_csv"] = write_csv(out / "discrepancy.csv", rows)
    paths["slopes_csv"] = write_csv(out / "slopes.csv", slopes)
    paths["spectra_csv"] = write_csv(out / "spectra.csv", spectra_rows)
    return paths

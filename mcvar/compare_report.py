"""Every method on every scene at equal time: CSV, PNG matrix and HTML (layer 7; ``mcvar compare``).

:func:`compare_report` runs :func:`mcvar.experiments.compare.measure_compare`
and writes into ``out``

* ``compare.csv``: one row per scene x method
  (:data:`~mcvar.experiments.compare.COMPARE_COLUMNS`): median spp, seconds
  and MSE over the seeds, MSE x time, efficiency ``1 / (MSE x time)``, the
  efficiency relative to the column's winner, the winner, and the reason of
  a method that refused the scene;
* ``compare_runs.csv``: every seed of every cell;
* ``compare.png``: the matrix, methods x scenes: each cell the equal-time
  image and its relative efficiency, the winner of each column framed, a
  refused cell its reason; the shared reference on top;
* ``compare.html``: the table, the figure, the references and why each was
  chosen, in the style of the convergence report (one self-contained file);
* with the pairs (``pairs=True``): ``pairs.csv`` (the slide pairs at equal
  time), ``strategies.csv`` and ``strategies/`` (BDPT's (s, t) strategies on
  ``cornell-caustic``: per-strategy energy and variance, the grid image
  ``strategies/strategies.png``), ``forward_tracing.csv`` (light tracing
  without the camera connection: rays through the pinhole) and
  ``radiosity_views.csv`` (one solve, two views).
"""
from __future__ import annotations

import html
import math
import os
import textwrap
from pathlib import Path

import numpy as np

from .experiments.compare import (PAIRS, CompareResult, StrategyGrid, forward_pinhole_hits, measure_compare,
                                  measure_pairs, measure_strategy_grid, radiosity_views)
from .experiments.slide_pairs import STRATEGY_COLUMNS
from .plotting import plt, save_figure
from .images import linear_to_srgb
from .pages import (CSS as _CSS, PRINT_JS as _PRINT_JS, details as _details, fmt as _fmt, img as _img,
                    table as _table, write_csv as _csv)

__all__ = ["compare_report", "write_compare", "plot_matrix", "compare_section", "pair_rows", "pairs_section",
           "VIEW_COLUMNS", "view_rows", "strategy_rows", "forward_rows", "write_strategy_grid"]

_WIN = "#2a9d3a"


def _tonemap(image) -> np.ndarray:
    return linear_to_srgb(np.clip(image, 0.0, None))


def _spp(x) -> str:
    return f"{x:.0f}" if np.isfinite(x) else "—"


def plot_matrix(result: CompareResult, path) -> Path:
    """``compare.png``: the reference row, then one row per method, one column per scene.

    A rendered cell shows its equal-time image (first seed) titled with its
    efficiency relative to the column's winner; the winner is framed green; a
    refused cell shows its reason.
    """
    rows, cols = 1 + len(result.methods), len(result.scenes)
    fig, axes = plt.subplots(rows, cols, figsize=(2.3 * cols + 0.9, 2.05 * rows), squeeze=False)
    for c, s in enumerate(result.scenes):
        ref = result.references[s]
        ax = axes[0, c]
        ax.imshow(_tonemap(ref.value))
        ax.set_title(f"{s}\nreference: {ref.method}, {ref.spp} spp", fontsize=7)
        winner = result.winner(s)
        for r, m in enumerate(result.methods, start=1):
            ax = axes[r, c]
            cell = result.cells.get((s, m))
            if cell is None:
                ax.text(0.5, 0.5, "not run\n(interrupted)", ha="center", va="center", fontsize=7)
                ax.set_facecolor("#eeeeee")
            elif not cell.rendered:
                ax.set_facecolor("#eeeeee")
                ax.text(0.04, 0.5, "\n".join(textwrap.wrap(cell.reason, 34)[:9]), ha="left", va="center",
                        fontsize=5, transform=ax.transAxes)
                ax.set_title("cannot render", fontsize=7)
            else:
                ax.imshow(_tonemap(cell.image))
                rel = result.relative_efficiency(s, m)
                star = "WINNER  " if m == winner else ""
                ax.set_title(f"{star}rel. eff. {rel:.2g}\nMSE {cell.mse:.2g}, {cell.spp:.0f} spp", fontsize=7,
                             color=_WIN if m == winner else "black",
                             fontweight="bold" if m == winner else "normal")
                if m == winner:
                    for spine in ax.spines.values():
                        spine.set_edgecolor(_WIN)
                        spine.set_linewidth(4)
            if c == 0:
                ax.set_ylabel(m, fontsize=9)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].set_ylabel("reference", fontsize=9)
    fig.suptitle(f"Equal time: {result.seconds:g} s per method and scene, {result.res} x {result.res} pixels, "
                 f"median of {result.seeds} seeds; efficiency = 1 / (MSE x time), relative to the column's "
                 "winner (framed)", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return save_figure(fig, path)


def compare_section(result: CompareResult, png=None, *, heading: str = "h2") -> str:
    """The matrix as an HTML section: relative efficiencies (winner marked, reasons
    in refused cells), the figure when given, and the numbers behind it."""
    head = "<th>method</th>" + "".join(f"<th>{html.escape(s)}</th>" for s in result.scenes)
    body = []
    for m in result.methods:
        tds = [f"<td>{html.escape(m)}</td>"]
        for s in result.scenes:
            cell = result.cells.get((s, m))
            if cell is None:
                tds.append("<td class='differs'>not run (interrupted)</td>")
            elif not cell.rendered:
                tds.append(f"<td class='differs' style='font-size:11px;text-align:left'>cannot render: "
                           f"{html.escape(cell.reason)}</td>")
            else:
                win = m == result.winner(s)
                text = f"{_fmt(result.relative_efficiency(s, m), 2)}<br><span class='note'>MSE {_fmt(cell.mse)}" \
                       f", {cell.spp:.0f} spp</span>"
                tds.append(f"<td class='agrees'><b>winner</b> {text}</td>" if win else f"<td>{text}</td>")
        body.append("<tr>" + "".join(tds) + "</tr>")
    table = f"<table class='chart'><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"
    numbers = _table(("scene", "method", "spp", "seconds", "MSE", "mean / reference mean", "MSE x time",
                      "efficiency", "relative"),
                     [(r["scene"], r["method"], _spp(r["spp"]), _fmt(r["seconds"]), _fmt(r["mse"]),
                       _fmt(r["mean_ratio"]), _fmt(r["mse_x_time"]), _fmt(r["efficiency"]),
                       _fmt(r["relative_efficiency"])) for r in result.rows() if not r["reason"]])
    refs = _table(("scene", "reference method", "spp", "noise (variance of its mean, in the region)", "seconds",
                   "why this method", "region of the MSE"),
                  [(s, ref.method, ref.spp, _fmt(result.reference_noise(s)), _fmt(ref.seconds), ref.why,
                    _region(result, s) or "whole image")
                   for s, ref in result.references.items()])
    parts = [f"<{heading}>Which method wins at equal time</{heading}>",
             f"<p>Each method renders each scene for {result.seconds:g} s of wall time (rounds of samples "
             f"per pixel until the time is spent), {result.seeds} seeds, {result.res} x {result.res} pixels. "
             "Each cell is the efficiency 1 / (MSE x time) of the medians, relative to the best method of "
             "its column (the <b>winner</b>), the MSE against the scene's shared reference and the spp "
             "that fitted in the time. A method that cannot render a scene says why.</p>",
             f"<div class='scroll'>{table}</div>"]
    if png is not None:
        parts.append(_img(png, "The equal-time images side by side (methods x scenes); the winner of each "
                               "column is framed."))
    parts.append(_details("The numbers behind each cell (medians over the seeds)", numbers))
    parts.append(_details("The references and why each method was chosen", refs, open_=True))
    return "\n".join(parts)


def _region(result: CompareResult, scene: str) -> str:
    for row in result.rows():
        if row["scene"] == scene:
            return row["region"]
    return ""


def pair_rows(pairs: dict) -> list[dict]:
    """Rows of ``pairs.csv``: one per pair and method, the cell's numbers and the lecture's claim."""
    rows = []
    for name, result in pairs.items():
        for row in result.rows():
            rows.append(dict(pair=name, **row, lecture=PAIRS[name][3]))
    return rows


#: Columns of ``radiosity_views.csv``.
VIEW_COLUMNS = ("quantity", "value")


def view_rows(views: dict) -> list[dict]:
    """Rows of ``radiosity_views.csv``: the solve, both views and the full render, timed, and the MSEs."""
    keys = ("solve_seconds", "view1_seconds", "view2_seconds", "full_seconds", "fraction", "mse1",
            "mse1_off_emitters", "mse2")
    return [dict(quantity=k, value=float(views[k])) for k in keys]


def strategy_rows(grid: StrategyGrid) -> list[dict]:
    """Rows of ``strategies.csv`` (:data:`~mcvar.experiments.slide_pairs.STRATEGY_COLUMNS`)."""
    return [{c: r[c] for c in STRATEGY_COLUMNS} for r in grid.rows]


def forward_rows(forward: dict) -> list[dict]:
    """Rows of ``forward_tracing.csv``: the counts of :func:`~mcvar.experiments.compare.forward_pinhole_hits`."""
    rows = [dict(quantity=k, value=forward[k]) for k in ("paths", "rays", "escaping", "hits", "energy_fraction",
                                                          "closest", "seconds")]
    rows += [dict(quantity=f"fraction of rays within {r:g} of the pinhole", value=v)
             for r, v in forward["within"].items()]
    return rows


def write_strategy_grid(grid: StrategyGrid, out) -> dict[str, Path]:
    """``strategies.csv`` and ``strategies/`` (``s{s}_t{t}.npy`` and the grid ``strategies.png``:
    :func:`mcvar.integrators.bdpt.write_strategies`) into ``out``."""
    from .integrators.bdpt import write_strategies

    out = Path(out)
    res = grid.image.shape[1], grid.image.shape[0]
    written = write_strategies(out / "strategies", grid.strategies, res, grid.max_depth)
    return {"strategies": _csv(out / "strategies.csv", strategy_rows(grid)), "strategies_png": written[-1]}


def _strategy_html(grid: StrategyGrid, png) -> str:
    rows = [(f"({r['s']}, {r['t']})", r["depth"], _fmt(r["share"]), _fmt(r["region_share"]),
             _fmt(r["region_variance"]), _fmt(r["pixel_variance"])) for r in grid.rows if r["energy"] > 0]
    carriers = ", ".join(f"({s}, {t})" for s, t in grid.carriers())
    text = (f"<h3>BDPT's (s, t) strategies on {html.escape(grid.scene)}</h3>"
            f"<p>{grid.renders} renders of {grid.spp} spp at max_depth {grid.max_depth} (every strategy kept: "
            "they sum to the image). s light vertices, t camera vertices; share of the image's energy and of "
            f"the caustic's ({html.escape(_region_text_of(grid.region))}), the variance of one render's caustic "
            f"mean and the mean pixel variance there. The caustic is carried by {carriers}.</p>")
    text += _table(("strategy (s, t)", "depth", "share of the image", "share of the caustic",
                    "variance of the caustic mean", "pixel variance in the caustic"), rows)
    if png is not None:
        text += _img(png, "Each strategy's weighted image: row = depth s + t - 1, column = s (exposure 4).")
    return text


def _region_text_of(region) -> str:
    from .experiments.compare_matrix import _region_text

    return _region_text(region) or "whole image"


def pairs_section(pairs: dict, views: dict | None = None, *, heading: str = "h2", grid: StrategyGrid | None = None,
                  grid_png=None, forward: dict | None = None) -> str:
    """The slide pairs as an HTML section: per pair the lecture's claim and the measured cells (and the
    BDPT strategy grid, forward tracing without the camera connection, radiosity's two views)."""
    parts = [f"<{heading}>The lecture's pairs, at equal time</{heading}>"]
    for name, result in pairs.items():
        scene = result.scenes[0] if result.scenes else PAIRS[name][0]
        rows = [(r["method"], _spp(r["spp"]), _fmt(r["seconds"]), _fmt(r["mse"]), _fmt(r["reference_noise"]),
                 _fmt(r["mean_ratio"]),
                 _fmt(r["efficiency"]), _fmt(r["relative_efficiency"]), r["winner"], r["reason"])
                for r in result.rows()]
        region = _region(result, scene) or "whole image"
        parts.append(f"<h3>{html.escape(name)} ({html.escape(scene)}; MSE over {html.escape(region)})</h3>"
                     f"<p>The lecture: {html.escape(PAIRS[name][3])}.</p>"
                     + _table(("method", "spp", "seconds", "MSE", "reference noise", "mean / reference mean",
                               "efficiency",
                               "relative", "winner", "reason"), rows))
    if forward is not None:
        parts.append(f"<h3>forward tracing without the camera connection ({html.escape(forward['scene'])})</h3>"
                     f"<p>{forward['paths']} light paths, {forward['rays']} rays ({forward['escaping']} leaving "
                     f"the scene): {forward['hits']} pass through the pinhole, so the image without the "
                     f"connection holds {forward['energy_fraction']:.3g} of the reference's energy (black). "
                     f"The closest ray passes {forward['closest']:.3g} units from it.</p>")
    if grid is not None:
        parts.append(_strategy_html(grid, grid_png))
    if views is not None:
        parts.append("<h3>radiosity: one solve, two views</h3>"
                     f"<p>Solve {views['solve_seconds']:.3f} s; view 1 from it {views['view1_seconds']:.3f} s, "
                     f"view 2 {views['view2_seconds']:.3f} s, against {views['full_seconds']:.3f} s for view 2 "
                     f"solved from scratch ({100 * views['fraction']:.0f} %). MSE against path-traced "
                     f"references: view 1 {views['mse1']:.3g} ({views['mse1_off_emitters']:.3g} without the pixels "
                     f"that see the light), view 2 {views['mse2']:.3g}.</p>")
    return "\n".join(parts)


def write_compare(result: CompareResult, out, *, command: str | None = None, pairs: dict | None = None,
                  views: dict | None = None, grid: StrategyGrid | None = None,
                  forward: dict | None = None) -> dict[str, Path]:
    """Write ``compare.csv``, ``compare_runs.csv``, ``compare.png`` and ``compare.html`` into ``out``
    (and ``pairs.csv``, ``radiosity_views.csv`` with a section of the page when ``pairs`` / ``views``
    are given: :func:`~mcvar.experiments.compare.measure_pairs`,
    :func:`~mcvar.experiments.compare.radiosity_views`)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = result.rows()
    if not rows:
        raise ValueError("nothing was measured (interrupted before the first cell)")
    paths = {"csv": _csv(out / "compare.csv", rows)}
    runs = result.run_rows()
    if runs:
        paths["runs"] = _csv(out / "compare_runs.csv", runs)
    paths["png"] = plot_matrix(result, out / "compare.png")
    extra = []
    if pairs:
        paths["pairs"] = _csv(out / "pairs.csv", pair_rows(pairs))
    if views is not None:
        paths["views"] = _csv(out / "radiosity_views.csv", view_rows(views))
    if forward is not None:
        paths["forward"] = _csv(out / "forward_tracing.csv", forward_rows(forward))
    if grid is not None:
        paths.update(write_strategy_grid(grid, out))
    if pairs or views is not None or grid is not None or forward is not None:
        extra.append(pairs_section(pairs or {}, views, grid=grid, grid_png=paths.get("strategies_png"),
                                   forward=forward))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    facts = [("scenes", ", ".join(result.scenes)), ("methods", ", ".join(result.methods)),
             ("seconds per method and scene", result.seconds), ("resolution", f"{result.res} x {result.res}"),
             ("seeds", result.seeds), ("root seed", result.seed), ("cores on this machine", os.cpu_count()),
             ("load average (1 min) when written", _fmt(load)), ("wall time", f"{result.wall_seconds:.1f} s")]
    if result.interrupted:
        facts.append(("interrupted", "yes: the cells finished before Ctrl-C"))
    if command:
        facts.append(("command", command))
    body = ["<h1>Rendering methods at equal time</h1>",
            f"<p class='lead'>{len(result.methods)} methods on {len(result.scenes)} scenes, "
            f"{result.seconds:g} s each, {result.wall_seconds:.0f} s in all.</p>",
            compare_section(result, paths["png"]),
            *extra,
            _details("Settings", _table(("setting", "value"), facts)),
            "<p class='note'>The numbers are in <code>compare.csv</code> (medians) and "
            "<code>compare_runs.csv</code> (every seed) beside this page.</p>"]
    page = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width,initial-scale=1'>"
            "<link rel='icon' href='data:,'><title>mcvar: rendering methods at equal time</title>"
            f"<style>{_CSS}</style>{_PRINT_JS}</head><body>" + "\n".join(body) + "</body></html>")
    paths["html"] = out / "compare.html"
    paths["html"].write_text(page, encoding="utf-8")
    np.savez_compressed(out / "compare_images.npz",
                        **{f"{s}__{m}": c.image for (s, m), c in result.cells.items() if c.rendered})
    return {"html": paths.pop("html"), **paths}


def compare_report(out, settings=None, *, scenes=None, methods=None, progress: bool = True,
                   command: str | None = None, pairs: bool = False, **fields) -> dict[str, Path]:
    """Measure the matrix (:func:`~mcvar.experiments.compare.measure_compare`) and write it into ``out``.

    ``settings`` (a :class:`~mcvar.experiments.compare.CompareSettings`),
    ``scenes``, ``methods`` and ``fields`` (``seconds``, ``res``, ``seeds``,
    ``seed``, ``references``, ``reference_spp``, ``regions``, ``options``)
    say what to measure. References are cached in ``out/.cache`` (a second
    run renders none). Ctrl-C writes the cells finished so far.
    ``pairs=True`` measures the slide pairs too
    (:func:`~mcvar.experiments.compare.measure_pairs`, the same references)
    BDPT's strategy grid on ``cornell-caustic``, forward tracing without the
    camera connection at the point light and radiosity's two views of one
    solve.

    Returns
    -------
    dict of str to Path
        ``html``, ``csv``, ``runs``, ``png`` (and ``pairs``, ``views``).
    """
    from .experiments.compare import check_compare_args, compare_settings

    if not isinstance(out, (str, os.PathLike)) or str(out) == "":
        raise TypeError(f"out must be a folder path; got {out!r}")
    st = compare_settings(settings, scenes, methods, **fields)
    check_compare_args(st.scenes, st.methods if st.methods is not None else ["path"], st.seconds, st.res, st.seeds)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out must be a folder; {out} exists and is not one")
    out.mkdir(parents=True, exist_ok=True)
    result = measure_compare(settings=st, cache_dir=out / ".cache", progress=progress)
    measured, views, grid, forward = None, None, None, None
    if pairs and not result.interrupted:
        try:
            measured = measure_pairs(seconds=st.seconds, res=st.res, seeds=st.seeds, seed=st.seed,
                                     cache_dir=out / ".cache", progress=progress, reference_spp=st.reference_spp)
            forward = forward_pinhole_hits("cornell-point", seed=st.seed)
            grid = measure_strategy_grid("cornell-caustic", res=st.res, seed=st.seed, progress=progress)
            views = radiosity_views("cornell", res=st.res, seed=st.seed, cache_dir=out / ".cache",
                                    reference_spp=(st.reference_spp or {}).get("cornell"))
        except KeyboardInterrupt:
            pass
    return write_compare(result, out, command=command, pairs=measured, views=views, grid=grid, forward=forward)

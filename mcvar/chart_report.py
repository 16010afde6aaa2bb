"""The lecture's 'Rendering Algorithm Chart', measured: CSV, PNG and HTML (layer 7; ``mcvar chart``).

:func:`chart_report` runs :func:`mcvar.experiments.measure_chart` and writes

* ``chart.csv``: one row per registered chart method, columns ``method,
  lecture_consistent, lecture_unbiased, consistent, unbiased, mse_x_time,
  note`` (:data:`mcvar.experiments.chart.CHART_COLUMNS`);
* ``chart.png``: the lecture's chart with the measured columns beside the
  lecture's, the cells that differ marked, and the one-line reason;
* ``chart.html``: the same table, the figure and the evidence behind every
  answer, in the style of the convergence report (one self-contained file).

:func:`chart_section` is the HTML section that ``mcvar demo`` adds to its report.
"""
from __future__ import annotations

import html
import os
import textwrap
from pathlib import Path

from .experiments.chart import CHART_COLUMNS, ChartResult, measure_chart
from .plotting import plt, save_figure
from .pages import (CSS as _CSS, PRINT_JS as _PRINT_JS, clauses as _clauses, details as _details,
                    fmt as _fmt, img as _img, table as _table, write_csv as _csv)

__all__ = ["chart_report", "chart_section", "write_chart", "plot_chart"]

# chart.png's cell colours (chart.html's come from the report's stylesheet: table.chart)
_AGREE, _DIFFER, _HEAD = "#e3f1e0", "#fbe2c5", "#e8e8e8"


def _chart_rows(result: ChartResult) -> list[dict]:
    return [row.csv_row() for row in result.rows]


def plot_chart(result: ChartResult, path) -> Path:
    """``chart.png``: the lecture's chart, the measured columns beside it.

    Measured cells that agree with the lecture are green, those that differ
    orange; the last column says why they differ.
    """
    header = ["method", "lecture:\nconsistent?", "lecture:\nunbiased?", "measured:\nconsistent",
              "measured:\nunbiased", "MSE x time\n(largest level)", "why they differ"]
    cells, colours = [], []
    for row in result.rows:
        note = "\n".join(textwrap.wrap(row.note, 70)) or "—"
        cells.append([row.method, row.lecture_consistent, row.lecture_unbiased, row.consistent, row.unbiased,
                      f"{row.mse_x_time:.3g}", note])
        c_ok = row.consistent == row.lecture_consistent
        u_ok = row.unbiased == row.lecture_unbiased
        colours.append(["white", "white", "white", _AGREE if c_ok else _DIFFER, _AGREE if u_ok else _DIFFER,
                        "white", "white"])
    lines = [2] + [max(1, c[-1].count("\n") + 1) for c in cells]  # text lines per row, header first
    units = [n + 0.8 for n in lines]
    fig, ax = plt.subplots(figsize=(12.5, 0.19 * sum(units)))
    ax.axis("off")
    table = ax.table(cellText=cells, colLabels=header, cellColours=colours,
                     colColours=[_HEAD] * len(header), colWidths=[0.1, 0.08, 0.08, 0.08, 0.08, 0.1, 0.48],
                     bbox=[0, 0, 1, 1], cellLoc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    for (r, c), cell in table.get_celld().items():
        cell.set_height(units[r] / sum(units))
        if c == len(header) - 1 and r > 0:
            cell.set_text_props(ha="left")
            cell.PAD = 0.02
    mode = "quick" if result.quick else "default"
    ax.set_title(f"The lecture's Rendering Algorithm Chart, measured on the Cornell box "
                 f"({result.res} x {result.res} pixels, {result.replicates} replicates per level, {mode})",
                 fontsize=10)
    return save_figure(fig, path)


def chart_section(result: ChartResult, png=None, *, heading: str = "h2") -> str:
    """The chart as an HTML section: the table (differing cells marked), the
    figure ``png`` when given, and the evidence behind every answer (collapsed)."""
    rows = []
    for row in result.rows:
        def cell(measured, lecture):
            cls = "agrees" if measured == lecture else "differs"
            return f"<td class='{cls}'>{html.escape(measured)}</td>"
        rows.append("<tr>" + f"<td>{html.escape(row.method)}</td>"
                    + f"<td>{html.escape(row.lecture_row)}</td>"
                    + f"<td>{html.escape(row.lecture_consistent)}</td><td>{html.escape(row.lecture_unbiased)}</td>"
                    + cell(row.consistent, row.lecture_consistent) + cell(row.unbiased, row.lecture_unbiased)
                    + f"<td>{_fmt(row.mse_x_time)}</td><td>{html.escape(row.note) or '—'}</td></tr>")
    head = "".join(f"<th>{h}</th>" for h in ("method", "lecture's row", "lecture: consistent?",
                                              "lecture: unbiased?", "measured: consistent",
                                              "measured: unbiased", "MSE x time", "why they differ"))
    table = f"<table class='chart'><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    evidence = []
    for row in result.rows:
        items = "".join(f"<li>{html.escape(part)}</li>" for part in _clauses(row.evidence))
        evidence.append(f"<h3>{html.escape(row.method)}: knob {html.escape(row.knob)}, levels "
                        f"{', '.join(map(str, row.levels))}, {row.seconds:.1f} s</h3>"
                        f"<ul class='evidence'>{items}</ul>")
    mode = "--quick" if result.quick else "default"
    parts = [
        f"<{heading}>Rendering Algorithm Chart, measured</{heading}>",
        "<p>The lecture's closing chart says of each method whether it is consistent and unbiased. "
        "Measured here on the Cornell box with the tests of <code>mcvar converge</code>: each method "
        "at increasing levels of its accuracy knob (samples per pixel, photons, iterations or mesh "
        f"refinement), {result.replicates} replicates per level at {result.res} x {result.res} pixels, "
        "against one path-traced reference. <b>unbiased</b>: no level's image mean differs from the "
        f"reference's (Welch t test, Sidak-corrected to family-wise alpha = {result.alpha:g}); "
        "<b>consistent</b>: the MSE falls over the levels and the bias vanishes. MSE x time is at the "
        f"largest level (1 / efficiency). Orange: measured differs from the lecture; the last column says "
        f"why. (<code>mcvar chart</code>, {mode} settings)</p>",
        table,
    ]
    parts.append(_details("Evidence behind each measured answer", *evidence))
    if png is not None:
        parts.append(_details("The chart as a figure (chart.png)",
                              _img(png, "The lecture's chart with the measured columns beside it; orange "
                                        "cells differ from the lecture.")))
    return "\n".join(parts)


def write_chart(result: ChartResult, out, *, command: str | None = None) -> dict[str, Path]:
    """Write ``chart.csv``, ``chart.png`` and ``chart.html`` of a measured chart into ``out``.

    Returns
    -------
    dict of str to Path
        ``html``, ``csv``, ``png``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = _chart_rows(result)
    if tuple(rows[0]) != CHART_COLUMNS:  # pragma: no cover (ChartRow.csv_row builds them)
        raise RuntimeError(f"chart.csv columns {tuple(rows[0])} are not {CHART_COLUMNS}")
    paths = {"csv": _csv(out / "chart.csv", rows), "png": plot_chart(result, out / "chart.png")}
    ref = result.reference
    facts = [("scene", "cornell"), ("resolution", f"{result.res} x {result.res}"),
             ("replicates per level", result.replicates), ("seed", result.seed),
             ("reference", ref.source), ("cores on this machine", os.cpu_count()),
             ("wall time", f"{result.seconds:.1f} s")]
    facts += [(f"{row.method}: knob", f"{row.knob}; levels {', '.join(map(str, row.levels))}")
              for row in result.rows]
    if command:
        facts.append(("command", command))
    body = ["<h1>Rendering methods: consistent? unbiased?</h1>",
            f"<p class='lead'>{len(result.rows)} registered methods on the Cornell box, "
            f"{result.seconds:.0f} s.</p>",
            chart_section(result, paths["png"]),
            _details("Settings", _table(("setting", "value"), facts)),
            "<p class='note'>The numbers are in <code>chart.csv</code> beside this page.</p>"]
    page = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width,initial-scale=1'>"
            "<link rel='icon' href='data:,'><title>mcvar: the rendering-methods chart, measured</title>"
            f"<style>{_CSS}</style>{_PRINT_JS}</head><body>" + "\n".join(body) + "</body></html>")
    paths["html"] = out / "chart.html"
    paths["html"].write_text(page, encoding="utf-8")
    return {"html": paths.pop("html"), **paths}


def chart_report(out, settings=None, *, command: str | None = None, **options) -> dict[str, Path]:
    """Measure the chart (:func:`mcvar.experiments.measure_chart`) and write it into ``out``.

    Finished runs and the reference are cached in ``out/.cache``: running it
    again (or after Ctrl-C) computes only what is missing. ``settings`` (a
    :class:`~mcvar.experiments.chart.ChartSettings`) and the keywords
    (``quick``, ``methods``, ``rng``, ``workers``, ``progress``, ``res``,
    ``replicates``, ``levels``, ``reference_spp``, ...: its fields) go to
    :func:`~mcvar.experiments.measure_chart`.

    Returns
    -------
    dict of str to Path
        ``html``, ``csv``, ``png``.
    """
    if not isinstance(out, (str, os.PathLike)) or str(out) == "":
        raise TypeError(f"out must be a folder path; got {out!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out must be a folder; {out} exists and is not one")
    try:  # fail before measuring, not after
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"out: cannot create the folder {out} ({exc.strerror or exc})") from exc
    result = measure_chart(settings, cache_dir=out / ".cache", **options)
    return write_chart(result, out, command=command)

"""The measured 'Rendering Algorithm Chart' as files: CSV, HTML and PNG (layer 7).

:func:`write_chart` turns a :class:`mcvar.experiments.chart.ChartResult`
into ``chart.csv`` (columns ``method, lecture_consistent, lecture_unbiased,
consistent, unbiased, mse_x_time, note``), ``chart.png`` (the lecture's chart
with the measured columns beside it, cells that differ outlined) and
``chart.html`` (both, plus the evidence behind every measured answer).
:func:`chart` runs the measurement and writes them (``mcvar chart``).
"""
from __future__ import annotations

import base64
import csv
import html
from pathlib import Path

from .plotting import plt, save_figure

__all__ = ["CSV_COLUMNS", "write_chart", "chart"]

#: Columns of chart.csv, in order.
CSV_COLUMNS = ("method", "lecture_consistent", "lecture_unbiased", "consistent", "unbiased", "mse_x_time", "note")
_COLOURS = {"yes": "#b8e0b8", "no": "#f2b8b8", "almost": "#f7dca0"}


def _png(result, path: Path) -> Path:
    rows = result.rows
    fig, ax = plt.subplots(figsize=(11.5, 0.45 * len(rows) + 1.2))
    ax.axis("off")
    header = ["method", "lecture row", "lecture\nconsistent?", "lecture\nunbiased?", "measured\nconsistent?",
              "measured\nunbiased?", "MSE x time (s)"]
    cells = [[r.method, r.lecture_row, r.lecture_consistent, r.lecture_unbiased, r.consistent, r.unbiased,
              f"{r.mse_x_time:.3g}"] for r in rows]
    table = ax.table(cellText=cells, colLabels=header, loc="center", cellLoc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.scale(1.0, 1.5)
    for i, r in enumerate(rows, start=1):
        for j, lecture, measured in ((2, r.lecture_consistent, r.consistent), (3, r.lecture_unbiased, r.unbiased)):
            table[i, j].set_facecolor(_COLOURS.get(lecture, "white"))
            cell = table[i, j + 2]
            cell.set_facecolor(_COLOURS.get(measured, "white"))
            if measured != lecture:
                cell.set_edgecolor("black")
                cell.set_linewidth(2.0)
    ax.set_title(f"Rendering Algorithm Chart: the lecture's answers and mcvar's measurements "
                 f"(Cornell box {result.res} x {result.res}, levels {list(result.levels)}, "
                 f"{result.replicates} replicates)", fontsize=10)
    return save_figure(fig, path)


def write_chart(result, out) -> dict:
    """Write ``chart.csv``, ``chart.png`` and ``chart.html`` for ``result`` into folder ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "chart.csv", "png": out / "chart.png", "html": out / "chart.html"}
    with open(paths["csv"], "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for r in result.rows:
            w.writerow([r.method, r.lecture_consistent, r.lecture_unbiased, r.consistent, r.unbiased,
                        f"{r.mse_x_time:.6g}", r.note])
    _png(result, paths["png"])
    img = base64.b64encode(paths["png"].read_bytes()).decode("ascii")
    head = "".join(f"<th>{html.escape(c)}</th>" for c in CSV_COLUMNS + ("evidence",))
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (
            r.method, r.lecture_consistent, r.lecture_unbiased, r.consistent, r.unbiased,
            f"{r.mse_x_time:.3g}", r.note or "as the lecture says", r.evidence)) + "</tr>"
        for r in result.rows)
    page = (
        "<!doctype html><html><head><meta charset='utf-8'><title>Rendering Algorithm Chart, measured</title>"
        "<style>body{font-family:sans-serif;max-width:75em;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #aaa;padding:.3em .5em;font-size:.9em;vertical-align:top}</style></head><body>"
        "<h1>Rendering Algorithm Chart, measured</h1>"
        f"<p>Every registered method on the Cornell box ({result.res} x {result.res} pixels) at accuracy "
        f"levels {list(result.levels)} (spp, or photons, iterations, mesh refinement: "
        "<code>mcvar.experiments.chart</code>), {result.replicates} replicates each, against one cached "
        "path-traced reference; 'unbiased' is the Welch test of the image mean at every level "
        "(Sidak-corrected), 'consistent' the fall of the MSE and of the bias from the first level to "
        f"the last, as in <code>mcvar converge</code>. MSE x time at the largest level. {result.seconds:.0f} s "
        "in all.</p>"
        f"<img alt='the chart' src='data:image/png;base64,{img}'/>"
        f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></body></html>")
    paths["html"].write_text(page)
    return paths


def chart(out, *, quick: bool = False, workers: int | None = None, cache_dir=None, progress: bool = True,
          **kwargs) -> dict:
    """Measure the chart (:func:`mcvar.experiments.chart.measure_chart`) and write it to ``out``.

    ``cache_dir`` defaults to ``out/cache`` (the reference and finished runs
    are reused by the next call).
    """
    from .experiments.chart import measure_chart

    cache_dir = Path(out) / "cache" if cache_dir is None else cache_dir
    result = measure_chart(quick=quick, workers=workers, cache_dir=cache_dir, progress=progress, **kwargs)
    return write_chart(result, out)

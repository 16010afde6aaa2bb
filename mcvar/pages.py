"""The pieces of mcvar's self-contained HTML report pages (layer 7).

The convergence report (:mod:`mcvar.report`), the chart (:mod:`mcvar.chart_report`)
and the samplers report share them: one stylesheet (:data:`CSS`), the script
that opens collapsed sections before printing (:data:`PRINT_JS`), CSV files
(:func:`write_csv`), tables, figures embedded as base64 PNG, collapsible
sections. They hold no experiment: a page module imports them, never the
other way round.
"""
from __future__ import annotations

import base64
import csv
import html
from pathlib import Path

import numpy as np

__all__ = ["CSS", "PRINT_JS", "write_csv", "fmt", "table", "data_uri", "img", "clauses", "details"]


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Write ``rows`` (dicts with the same keys) to ``path`` as CSV (floats by ``repr``: no digit lost); return the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(float(v)) if isinstance(v, float) else v) for k, v in row.items()})
    return path


def fmt(x, digits=3) -> str:
    """A number for a table cell: yes/no for bools, integers as they are, ``digits`` significant digits."""
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(x)
    if not np.isfinite(x):
        return str(x)
    return f"{x:.{digits}g}"


def table(header, rows, *, cls: str = "") -> str:
    """An HTML table, every cell escaped."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    attr = f' class="{cls}"' if cls else ""
    return f"<table{attr}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def data_uri(png: bytes) -> str:
    """PNG bytes as a ``data:`` URI."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def img(path: Path, alt: str) -> str:
    """A figure with the PNG at ``path`` embedded (base64) and ``alt`` as its caption."""
    return f'<figure><img alt="{html.escape(alt)}" src="{data_uri(Path(path).read_bytes())}"/>' \
           f"<figcaption>{html.escape(alt)}</figcaption></figure>"


def clauses(text: str) -> list[str]:
    """Split evidence at the '; ' that are outside parentheses."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += (ch == "(") - (ch == ")")
        if depth == 0 and text.startswith("; ", i):
            parts.append(text[start:i])
            start = i + 2
    return [p for p in parts + [text[start:]] if p]


def details(summary: str, *content: str, open_: bool = False) -> str:
    """A collapsible section (open when ``open_``)."""
    attr = " open" if open_ else ""
    return f"<details{attr}><summary>{html.escape(summary)}</summary>{''.join(content)}</details>"


#: The stylesheet of every report page.
CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:1.5em auto;padding:0 1em;color:#222;
line-height:1.45}h1{font-size:1.6em;margin-bottom:.2em}h2{margin-top:1.4em}.lead{color:#555;margin-top:0}
table{border-collapse:collapse;font-size:13px;margin:.5em 0 1em}td,th{border:1px solid #ccc;padding:3px 7px;
text-align:right}th{background:#f3f3f3}td:first-child,td:nth-child(2){text-align:left}
table.verdicts td{text-align:center}table.verdicts td:first-child{text-align:left;font-weight:600}
img{max-width:100%}figure{margin:.6em 0}figcaption{font-size:12px;color:#555}code{background:#f3f3f3}
.tiles{display:flex;flex-wrap:wrap;gap:12px}.col{display:flex;flex-direction:column}
.tile img{width:256px;height:auto;image-rendering:pixelated}
.note{font-size:12px;color:#555}.scroll{overflow-x:auto}details{border:1px solid #ddd;border-radius:4px;padding:.3em .8em;
margin:.6em 0}summary{cursor:pointer;font-weight:600}ul.evidence li{margin:.2em 0}
table.chart td,table.chart th{text-align:center}table.chart td:first-child,table.chart td:nth-child(2){text-align:left}
table.chart td:first-child{font-weight:600}table.chart td:last-child{text-align:left;max-width:30em}
table.chart td.differs{background:#fbe2c5}table.chart td.agrees{background:#e3f1e0}
@media print{body{max-width:none;margin:0}details{border:none;padding:0}
details::details-content{content-visibility:visible;display:contents}
summary{list-style:none;font-size:1.2em}figure,tr,.tiles{break-inside:avoid}
.scroll{overflow:visible}table.configs{font-size:9px}}"""

# Opens every collapsed section before printing (print CSS covers browsers with ::details-content).
PRINT_JS = ("<script>addEventListener('beforeprint',function(){document.querySelectorAll('details')"
             ".forEach(function(d){d.open=true})})</script>")

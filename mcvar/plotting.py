"""Shared matplotlib helpers (layer 7: the only layer that imports matplotlib).

Figures are saved as files a person can open (PNG by default). The backend is
left to matplotlib (Agg on a machine with no screen, inline in a notebook):
setting it on import would hide a notebook's figures.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt

from .metrics import LogLogFit, loglog_fit

__all__ = ["plt", "save_figure", "plot_loglog"]


def save_figure(fig, path, *, dpi: int = 120) -> Path:
    """Save ``fig`` to ``path`` (parent folders created) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_loglog(ax, x, y, *, label: str, fit: bool = True, yerr=None, **kwargs) -> LogLogFit | None:
    """Plot ``y`` against ``x`` on log-log axes, with an optional fitted line.

    The legend entry carries the fitted slope and its standard error, e.g.
    ``sobol (slope -0.98 +- 0.03)``. Returns the fit (or None).
    """
    result = loglog_fit(x, y) if fit and len(x) >= 3 else None
    if result is not None:
        label = f"{label} (slope {result.slope:.2f} ± {result.slope_stderr:.2f})"
    line = ax.errorbar(x, y, yerr=yerr, marker="o", ms=3, label=label, **kwargs)
    if result is not None:
        ax.plot(x, result.predict(x), ls="--", lw=0.8, color=line[0].get_color())
    ax.set_xscale("log")
    ax.set_yscale("log")
    return result

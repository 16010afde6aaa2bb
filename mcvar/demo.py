"""``mcvar demo``: the README's Cornell-box convergence report with the measured chart (layer 9).

:func:`demo` runs :func:`mcvar.report.convergence_report` and
:func:`mcvar.chart_report.write_chart`; it is its own module so that neither
report imports the other (formerly ``mcvar.report.demo``).
"""
from __future__ import annotations

from pathlib import Path

from .chart_report import chart_section, write_chart
from .experiments import measure_chart, scene_target
from .report import convergence_report

__all__ = ["demo", "DEMO_SETTINGS", "compare_link"]

#: What ``mcvar demo`` runs: 64 x 64 pixels in 25 s on a shared 2-core machine at
#: load ~2, 44-56 s at load 5-7 (the former 32 x 32 up to 256 spp with 8 replicates
#: took 50-76 s there; 64 x 64 with those levels took 9 minutes). The reference is
#: 8 chunks of 256 spp. ``chart``: keyword arguments of :func:`mcvar.experiments.measure_chart`
#: for the report's measured rendering-methods chart (written to ``out/chart``; None: no chart).
DEMO_SETTINGS = dict(methods=("path", "path:3", "direct"), samplers=("random", "jittered", "sobol"),
                     spp=(1, 4, 16, 64), replicates=6, res=64, rng=0, reference_spp=256,
                     chart=dict(quick=True))


def compare_link(out) -> str:
    """The report's section that links the equal-time comparison (issue 21): ``compare/compare.html``
    beside the report when ``mcvar compare --pairs --out OUT/compare`` has written it, the command
    otherwise, and the docs page *Choosing a method* (``docs/compare.md``) and notebook 10."""
    page = Path(out) / "compare" / "compare.html"
    where = ("<a href='compare/compare.html'>compare/compare.html</a> (beside this page)" if page.is_file() else
             "<code>compare/compare.html</code> once <code>mcvar compare --pairs --out "
             f"{Path(out) / 'compare'}</code> has run (a few minutes)")
    return ("<h2>Choosing a method: every method at equal time</h2>"
            "<p>This report measures how path tracing converges on one scene; which method wins where "
            "(path tracing, BDPT, light tracing, Metropolis, photon mapping, radiosity on the scenes made "
            "for them, at equal wall time, efficiency 1 / (MSE x time)) is measured by "
            f"<code>mcvar compare</code>: {where}. Its numbers and the reasons are on the docs page "
            "<i>Choosing a method</i> (<code>docs/compare.md</code>) and in notebook 10 "
            "(<code>notebooks/10_choosing_a_method.ipynb</code>).</p>")


def demo(out, *, progress: bool = True, workers: int | None = None) -> dict[str, Path]:
    """The default Cornell-box convergence report (``mcvar demo``).

    Runs :func:`convergence_report` on ``'cornell'`` with
    :data:`DEMO_SETTINGS`: path tracing with Russian roulette (unbiased),
    path tracing stopped at depth 3 (biased: the light of longer paths is
    missing) and direct lighting, each with the random, jittered and Sobol
    samplers at 1, 4, 16 and 64 spp, 6 replicates, 64 x 64 pixels, against a
    reference of 8 x 256 spp (its own variance enters every test).

    The report includes the lecture's Rendering Algorithm Chart measured by
    ``mcvar chart --quick`` (:mod:`mcvar.chart_report`; its files in
    ``out/chart``) and links the equal-time comparison (:func:`compare_link`).
    """
    s = DEMO_SETTINGS
    sections, chart_paths = [], {}
    if s.get("chart") is not None:
        chart = measure_chart(workers=workers, progress=progress, cache_dir=Path(out) / "chart" / ".cache",
                              **s["chart"])
        chart_paths = write_chart(chart, Path(out) / "chart", command="mcvar chart --quick")
        sections.append(chart_section(chart, chart_paths["png"])
                        + "<p class='note'>Also in <code>chart/chart.html</code> and <code>chart/chart.csv"
                          "</code> beside this page.</p>")
    sections.append(compare_link(out))
    target = scene_target("cornell", res=s["res"], reference_spp=s.get("reference_spp", 1024))
    paths = convergence_report(target, out, methods=s["methods"], samplers=s["samplers"], spp=s["spp"],
                               replicates=s["replicates"], res=s["res"], rng=s.get("rng", s.get("seed", 0)),
                               workers=workers, progress=progress, sections=sections)
    return {**paths, **{f"chart_{k}": v for k, v in chart_paths.items()}}

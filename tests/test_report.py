"""Tests of mcvar.report: the convergence report's files, numbers and page."""
from __future__ import annotations

import csv
import re

import numpy as np
import pytest

from mcvar import experiments as ex
from mcvar import report
from mcvar.cli import main
from test_experiments import Counting, fake_target

EXPECTED = {"html", "csv", "fits_csv", "variance", "mse_time", "bias", "efficiency", "images"}


@pytest.fixture(scope="module")
def fake_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    target = fake_target(methods=("unbiased", "biased"), samplers=("random", "half"), spp=(1, 4, 16, 64))
    paths = report.convergence_report(target, out, replicates=6, rng=31337, workers=1, progress=False)
    return out, target, paths


def test_report_writes_every_file(fake_report):
    out, _, paths = fake_report
    assert set(paths) == EXPECTED and list(paths)[0] == "html"
    for path in paths.values():
        assert path.parent == out and path.stat().st_size > 0
    for key in EXPECTED - {"html", "csv", "fits_csv"}:
        assert paths[key].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_html_is_self_contained_and_states_results(fake_report):
    _, _, paths = fake_report
    page = paths["html"].read_text()
    sources = re.findall(r'src="([^"]*)"', page)
    # 5 figures + the reference + an estimate and an error map per method
    assert len(sources) == 5 + 1 + 2 * 2 and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "http" not in page.replace("http-equiv", "")  # nothing fetched from elsewhere
    verdicts = page.split('class="verdicts"')[1].split("</table>")[0]
    assert "<td>unbiased</td><td>yes</td><td>yes</td><td>both</td>" in verdicts
    assert "<td>biased</td><td>no</td><td>no</td><td>neither</td>" in verdicts
    assert "Sidak" in page and "± " in page
    # the verdicts, the frontier and the images come before the first collapsed section
    first_details = page.index("<details")
    assert page.index('class="verdicts"') < page.index("Speed for accuracy") < page.index('class="tiles"') \
        < first_details
    assert page.count("<details") == 5 and "beforeprint" in page and "@media print" in page


def test_csv_holds_the_sweeps_numbers_and_the_table_is_ranked(fake_report):
    out, target, paths = fake_report
    with open(paths["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 * 2 * 4
    # the same sweep again (all runs now cached) gives the same numbers as the CSV
    again = ex.sweep(target, methods=("unbiased", "biased"), samplers=("random", "half"), replicates=6,
                     rng=31337, workers=1, progress=False, cache_dir=out / ".cache")
    assert again.computed == 0
    for row, m in zip(rows, again.metrics):
        assert (row["method"], row["sampler"], int(row["spp"])) == (m.method, m.sampler, m.spp)
        assert float(row["mse"]) == m.mse and float(row["bias_pvalue"]) == m.bias_pvalue
    # figure-of-merit table: ranks 1..n with MSE x time ascending
    page = paths["html"].read_text()
    table = page.split("figure of merit MSE x time")[1].split("</table>")[0]
    foms = [float(r[4]) for r in re.findall(r"<tr><td>(\d+)</td><td>(\w+)</td><td>(\w+)</td>"
                                            r"<td>(\d+)</td><td>([^<]+)</td>", table)]
    assert len(foms) == 16 and foms == sorted(foms)
    with open(paths["fits_csv"]) as fh:
        fits = list(csv.DictReader(fh))
    assert len(fits) == 4 and all(float(f["variance_slope_stderr"]) > 0 for f in fits)


def test_rerun_resumes_from_the_cache(fake_report, tmp_path):
    out, _, _ = fake_report
    counting = Counting()
    target = fake_target(evaluate=counting, methods=("unbiased", "biased"), samplers=("random", "half"),
                         spp=(1, 4, 16, 64))
    report.convergence_report(target, out, replicates=6, rng=31337, workers=1, progress=False)
    assert counting.calls == 0


def test_integrand_values_need_no_image_panel(tmp_path):
    target = fake_target(evaluate=_scalar, exact=np.array([1.0]), reference_task=None)
    paths = report.convergence_report(target, tmp_path, replicates=4, rng=7, workers=1, progress=False)
    assert "images" not in paths and "N levels" in paths["html"].read_text()


def _scalar(method, sampler, spp, rng):
    return np.array([1.0 + rng.standard_normal() / np.sqrt(spp)])


def test_cli_converge_reports_bad_target(capsys, tmp_path):
    assert main(["converge", "no-such-target", "--out", str(tmp_path), "--quiet"]) == 2
    assert "no-such-target" in capsys.readouterr().err


def test_cli_converge_on_an_integrand(tmp_path, capsys):
    assert main(["converge", "checkerboard", "--out", str(tmp_path), "--quiet", "--workers", "1",
                 "--samplers", "random,jittered", "--spp", "1,4,16,64", "--replicates", "8"]) == 0
    printed = capsys.readouterr().out
    assert f"html: {tmp_path / 'report.html'}" in printed
    with open(tmp_path / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    # two estimators x two samplers x four N; the 'importance' estimator has
    # zero variance (its contribution is always 2) and zero bias
    assert len(rows) == 16
    assert all(float(r["variance"]) == 0 and float(r["bias"]) == 0 for r in rows if r["method"] == "importance")


def test_demo_runs_its_settings(tmp_path, monkeypatch, capsys):
    pytest.importorskip("mcvar.integrators")
    import mcvar.demo

    tiny = dict(mcvar.demo.DEMO_SETTINGS, methods=("path", "path:2"), samplers=("random",), spp=(1, 4, 16),
                replicates=3, res=4, chart=dict(quick=True, methods=("path",), res=4, replicates=3,
                                                levels=(1, 4), reference_spp=16, reference_chunks=2))
    monkeypatch.setattr(mcvar.demo, "DEMO_SETTINGS", tiny)
    assert main(["demo", "--out", str(tmp_path), "--quiet"]) == 0
    page = (tmp_path / "report.html").read_text()
    assert "Convergence report: cornell" in page and "4 x 4" in page
    assert (tmp_path / "images.png").is_file()
    # the measured rendering-methods chart is a section of the page, its files beside it
    assert "Rendering Algorithm Chart, measured" in page and "<td>path</td><td>Path Tracing</td>" in page
    assert (tmp_path / "chart" / "chart.csv").read_text().startswith(
        "method,lecture_consistent,lecture_unbiased,consistent,unbiased,mse_x_time,note")
    # the equal-time comparison is linked: its command before it ran, its page once written
    assert "Choosing a method" in page and "docs/compare.md" in page and "mcvar compare --pairs" in page
    (tmp_path / "compare").mkdir()
    (tmp_path / "compare" / "compare.html").write_text("<html></html>")
    assert "href='compare/compare.html'" in mcvar.demo.compare_link(tmp_path)


def test_cli_converge_uses_a_user_supplied_reference(tmp_path, capsys):
    # The checkerboard's 'importance' estimator is exact (always 2): against a
    # supplied reference of 2.5 its bias must read exactly -0.5.
    ref = tmp_path / "ref.npy"
    np.save(ref, np.array([2.5]))
    out = tmp_path / "out"
    assert main(["converge", "checkerboard", "--out", str(out), "--quiet", "--workers", "1",
                 "--samplers", "random", "--spp", "1,4,16", "--replicates", "4",
                 "--reference", str(ref)]) == 0
    with open(out / "results.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["method"] == "importance"]
    assert rows and all(float(r["bias"]) == -0.5 for r in rows)


def test_pareto_front_keeps_exactly_the_undominated_points():
    pts = [(1.0, 5.0), (2.0, 3.0), (2.0, 4.0), (3.0, 3.0), (4.0, 1.0), (5.0, 2.0), (1.0, 5.0)]
    # (2,4) is beaten by (2,3); (3,3) by (2,3); (5,2) by (4,1); the duplicate (1,5) ties, so both stay
    assert report.pareto_front(pts).tolist() == [True, True, False, False, True, False, True]


def test_lecture_claims_come_from_the_chart_and_the_bias_slides():
    assert report.lecture_claim("cornell", "path") == ("almost", "almost")
    assert report.lecture_claim("cornell", "photon") == ("yes", "no")
    assert report.lecture_claim("cornell", "path:3") is None  # the chart says nothing of a depth limit
    assert report.lecture_claim("cornell", "direct") is None
    assert report.lecture_claim("lecture", "grid") == ("yes", "no")
    assert report.lecture_claim("lecture", "single") == ("no", "yes")

"""The measured rendering-methods chart: files, columns, and the measured
answers for methods whose truth is known (path tracing with Russian roulette
is unbiased; the rasterizer's missing shadows are a bias)."""
import csv

import pytest

from mcvar.chart_figure import CSV_COLUMNS, write_chart
from mcvar.cli import main
from mcvar.experiments.chart import (CHART_METHODS, EXPECTED, LECTURE_CHART, _note, measure_chart,
                                     registered_chart_methods)


def test_lecture_table_is_the_slide():
    assert LECTURE_CHART["Photon Mapping"] == ("yes", "no")
    assert LECTURE_CHART["Path Tracing"] == ("almost", "almost")
    assert LECTURE_CHART["Finite Element Radiosity"] == ("no", "no")
    assert set(CHART_METHODS) == set(EXPECTED) == {"raster", "path", "path_depth3", "light", "bdpt",
                                                   "pssmlt", "photon", "sppm", "radiosity"}
    assert set(CHART_METHODS.values()) <= set(LECTURE_CHART)


def test_notes():
    assert _note("raster", ("no", "no"), ("no", "no"), "") == ""
    assert "Russian roulette" in _note("path", ("yes", "yes"), ("almost", "almost"), "")
    assert "did not detect the bias" in _note("path_depth3", ("no", "yes"), ("almost", "almost"), "")


@pytest.fixture(scope="module")
def small_chart(tmp_path_factory):
    cache = tmp_path_factory.mktemp("chart-cache")
    # raster's bias (no shadows) is large; 8 replicates give the Welch test 7 degrees of freedom
    return measure_chart(quick=True, methods=("raster", "path"), levels=(1, 4, 16, 64), replicates=8, res=16, workers=1,
                         cache_dir=cache, progress=False)


def test_measured_answers(small_chart):
    rows = {r.method: r for r in small_chart.rows}
    assert rows["raster"].unbiased == "no"
    assert rows["path"].unbiased == "yes" and rows["path"].consistent == "yes"
    assert rows["path"].note and rows["raster"].mse_x_time > 0


def test_files(small_chart, tmp_path):
    paths = write_chart(small_chart, tmp_path)
    with open(paths["csv"]) as fh:
        table = list(csv.reader(fh))
    assert tuple(table[0]) == CSV_COLUMNS
    assert [r[0] for r in table[1:]] == ["raster", "path"]
    for r in table[1:]:
        assert r[1] in ("yes", "no", "almost") and r[3] in ("yes", "no") and r[4] in ("yes", "no")
        assert float(r[5]) > 0
    assert paths["png"].stat().st_size > 1000
    page = paths["html"].read_text()
    assert "Rendering Algorithm Chart" in page and "bias test" in page


def test_bad_input():
    with pytest.raises(ValueError, match="chart methods"):
        measure_chart(methods=("nope",))
    missing = [m for m in CHART_METHODS if m not in registered_chart_methods()]
    if missing:
        with pytest.raises(ValueError, match="not registered"):
            measure_chart(methods=(missing[0],))


def test_cli_parses_chart(monkeypatch, tmp_path):
    seen = {}

    def fake_chart(out, **kw):
        seen.update(out=out, **kw)
        return {"csv": out / "chart.csv"}

    monkeypatch.setattr("mcvar.chart_figure.chart", fake_chart)
    assert main(["chart", "--out", str(tmp_path), "--quick", "--quiet"]) == 0
    assert seen["quick"] is True and seen["out"] == tmp_path

"""``mcvar chart``: the lecture's Rendering Algorithm Chart, measured (issue 13)."""
import csv
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcvar.integrators")

import mcvar.integrators as integrators  # noqa: E402
from mcvar.chart_report import chart_report  # noqa: E402
from mcvar.cli import main  # noqa: E402
from mcvar.experiments import chart  # noqa: E402

ALL = ("raster", "path", "path:3", "light", "bdpt", "pssmlt", "photon", "sppm", "radiosity")
TINY = dict(res=4, replicates=3, levels=(1, 4), reference_spp=16, reference_chunks=2)


def _registered():
    names = tuple(getattr(integrators, "METHODS", None) or integrators.INTEGRATORS)
    return [m for m in ALL if m.split(":")[0] in names]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache for the module: the 16 x 16 reference is rendered once."""
    return tmp_path_factory.mktemp("chart-cache")


@pytest.fixture(scope="module")
def measured(cache):
    """path, path:3 (asked for by its alias 'path_depth3') and raster on a 16 x 16 Cornell box.
    Power of the sweep's own bias
    test (Welch t, Sidak-corrected alpha = 1e-3 over 5 levels, |t| > ~6 with 9 degrees of
    freedom): depth 3 misses ~10 % of the image mean (~0.012); at 1024 spp the replicate
    mean's standard error (per-pixel variance ~0.6 at 1 spp, 256 pixels, 10 replicates) is
    ~5e-4 and the reference's (8 x 2048 spp) ~4e-4, so |t| ~ 20: detected."""
    return chart.measure_chart(methods=["raster", "path", "path_depth3"], res=16, replicates=10,
                               levels=(1, 4, 16, 64, 1024), reference_spp=2048, reference_chunks=8,
                               workers=1, progress=False, rng=3, cache_dir=cache)


def test_blur_and_mesh_bias_are_measured(measured, cache):
    """Photon mapping at a fixed radius and radiosity: their biases cancel in the image mean
    (the mean's t test missed both on the quick chart) but not per 4 x 4 block. Power, from
    the quick chart's runs at 10 replicates: photon mapping's block p-value 5e-7 at level 4
    and radiosity's 2e-7 at level 4, against the Sidak level 1 - (1 - 1e-3)^(1/4) = 2.5e-4
    of two levels x two tests."""
    names = _registered()
    methods = [m for m in ("photon", "radiosity") if m in names]
    if not methods:
        pytest.skip("photon and radiosity are not registered")
    result = chart.measure_chart(methods=methods, res=16, replicates=10, levels=(4, 16),
                                 reference_spp=2048, reference_chunks=8, workers=1, progress=False,
                                 rng=3, cache_dir=cache)
    assert result.reference.source.startswith("cache:")   # the `measured` fixture's reference
    for row in result.rows:
        assert row.unbiased == "no", row.evidence
        assert "block test" in row.evidence and "levels reject zero bias" in row.evidence
        assert not row.evidence.startswith("block test (4x4 pixel blocks, emitter pixels excluded): 0 of")


def test_path_is_measured_unbiased_and_consistent_and_a_fixed_depth_biased(measured):
    rows = {r.method: r for r in measured.rows}
    assert (rows["path"].consistent, rows["path"].unbiased) == ("yes", "yes"), rows["path"].evidence
    assert (rows["path:3"].consistent, rows["path:3"].unbiased) == ("no", "no"), \
        rows["path:3"].evidence
    assert rows["raster"].unbiased == "no"
    # a fixed depth loses light: its bias is negative, detected at the largest level
    last = [m for m in measured.sweeps["path:3"].metrics if m.spp == 1024][0]
    assert last.bias_detected and last.bias < 0
    # the lecture says 'almost' for path tracing: both rows differ and say why
    assert rows["path"].differs and "Russian roulette" in rows["path"].note
    assert rows["path:3"].differs and "fixed depth" in rows["path:3"].note
    assert not rows["raster"].differs and rows["raster"].note == ""
    assert all(r.mse_x_time > 0 and np.isfinite(r.mse_x_time) for r in measured.rows)


def test_chart_csv_has_the_columns_and_one_row_per_registered_method(tmp_path):
    paths = chart_report(tmp_path, workers=1, progress=False, **TINY)
    with open(paths["csv"], newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert tuple(reader.fieldnames) == chart.CHART_COLUMNS
    assert [r["method"] for r in rows] == _registered()
    for r in rows:
        assert (r["lecture_consistent"], r["lecture_unbiased"]) == chart.lecture_chart_claim(r["method"])
        assert r["consistent"] in ("yes", "no") and r["unbiased"] in ("yes", "no")
        # MSE is measured minus the reference's own noise and clipped at 0: at these tiny
        # settings a method can land at or below that floor (light, bdpt with some seeds)
        assert np.isfinite(float(r["mse_x_time"])) and float(r["mse_x_time"]) >= 0
        differs = (r["consistent"], r["unbiased"]) != (r["lecture_consistent"], r["lecture_unbiased"])
        assert bool(r["note"]) == differs or "knob" in r["note"]
    page = paths["html"].read_text()
    assert all(f"<td>{r['method']}</td>" in page for r in rows)
    assert paths["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the lecture's own claims, keyed by method
    assert chart.lecture_chart_claim("raster") == ("no", "no")
    assert chart.lecture_chart_claim("path") == ("almost", "almost")
    assert chart.lecture_chart_claim("photon") == ("yes", "no")
    assert chart.lecture_chart_claim("radiosity") == ("no", "no")


def _toy(name, **chart_fields):
    from mcvar.integrators import Method, get_method

    return Method(name, "camera", get_method("path").run_batch, "a toy", **chart_fields)


def test_rows_come_from_the_registry_and_the_slide_is_quoted(monkeypatch):
    """Each row's membership, knob and theory are fields of its Method record."""
    methods = integrators.METHODS
    assert chart.chart_methods() == tuple(m for m in ALL if m.split(":")[0] in methods)
    # a method on a slide row sits in that row's place; one on no row needs a knob and a lecture claim
    monkeypatch.setitem(methods, "mine", _toy("mine", lecture=("no", "yes"),
                                              knob=chart.spp_knob("mine", bounces=2)))
    monkeypatch.setitem(methods, "mine_bdpt", _toy("mine_bdpt", chart_row="Bidirectional Path Tracing",
                                                   theory=("yes", "yes", "it is BDPT")))
    monkeypatch.setitem(methods, "no_knob", _toy("no_knob", lecture=("no", "no")))       # no row
    rows = chart.chart_methods()
    assert rows.index("mine_bdpt") == rows.index("bdpt") + 1 and rows[-1] == "mine" and "no_knob" not in rows
    assert chart.lecture_chart_claim("path") == ("almost", "almost")      # the slide, not Method.lecture
    assert chart.lecture_chart_claim("path:3") == ("almost", "almost")
    assert chart.lecture_chart_claim("path_depth3") == ("almost", "almost")  # the alias
    assert chart.lecture_chart_claim("sppm") == ("yes", "no")             # the slide's photon mapping row
    assert chart.lecture_chart_claim("mine_bdpt") == ("yes", "yes")
    assert chart.lecture_chart_claim("mine") == ("no", "yes")             # on no slide row: the registry's
    with pytest.raises(ValueError, match="'direct_bsdf' has no lecture claim"):
        chart.lecture_chart_claim("direct_bsdf")
    assert chart.chart_theory("path:3")[:2] == ("no", "no") and chart.chart_theory("mine_bdpt")[2] == "it is BDPT"
    assert chart.chart_knob("path:3").options(8) == {"integrator": "path", "spp": 8, "max_depth": 3}
    # sppm's knob asks for 'photons' and 'radius' (accepted); a knob asking for an option the method lacks falls back
    knob, note = chart._knob_for("sppm")
    assert knob is integrators.METHODS["sppm"].knob and note == ""
    knob, note = chart._knob_for("mine")
    assert knob.counts == "spp" and "bounces" in note and knob.options(8) == {"integrator": "mine", "spp": 8}
    # the former tables are read-only snapshots of the registry
    with pytest.warns(DeprecationWarning):
        assert chart.KNOBS["sppm"] is integrators.METHODS["sppm"].knob and "mine" in chart.THEORY


def test_register_knob_sets_the_records_knob(monkeypatch):
    monkeypatch.setitem(integrators.METHODS, "path", integrators.METHODS["path"])   # restored afterwards
    with pytest.raises(TypeError, match="knob must be a Knob"):
        chart.register_knob("path", {"spp": 1})
    with pytest.raises(ValueError, match="knob.quick must hold >= 2 increasing"):
        chart.register_knob("path", chart.Knob("spp", chart.spp_knob("path").options, quick=(4, 1)))
    with pytest.raises(ValueError, match="'newmethod' is not registered"):
        chart.register_knob("newmethod", chart.spp_knob("newmethod"))
    knob = chart.register_knob("path", chart.Knob("spp", chart.spp_knob("path").options, quick=(2, 8)))
    assert integrators.METHODS["path"].knob is knob and chart.chart_knob("path:3").quick == (2, 8)


def test_cli_errors_are_clear(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["chart", "--out", str(afile), "--quiet", "--workers", "1"]) == 2
    assert "out must be a folder" in capsys.readouterr().err
    assert main(["chart", "--out", str(afile / "sub"), "--quiet", "--workers", "1"]) == 2
    assert "out: cannot create the folder" in capsys.readouterr().err
    assert main(["chart", "--out", str(tmp_path / "o"), "--methods", "path,pathh", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "mcvar chart: error: methods must be chart methods" in err and "'pathh'" in err
    missing = [m for m in ALL if m not in _registered()]
    if missing:  # a chart method whose integrator has not registered (yet)
        assert main(["chart", "--out", str(tmp_path / "o"), "--methods", missing[0], "--quiet"]) == 2
        assert "methods must be chart methods" in capsys.readouterr().err
    with pytest.raises(ValueError, match="levels must hold >= 2"):
        chart.measure_chart(methods=["path"], levels=[4], workers=1, progress=False)


CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


def test_chart_page_in_a_real_browser(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    if CHROMIUM is None:
        pytest.skip("no Chromium browser installed")
    paths = chart_report(tmp_path, methods=["path", "path:3"], workers=1, progress=False, **TINY)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                    args=["--headless", "--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page()
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(paths["html"].resolve().as_uri(), wait_until="load")
            cells = page.eval_on_selector_all("table.chart tbody tr",
                                              "rows => rows.map(r => [...r.cells].map(c => c.textContent))")
            marked = page.eval_on_selector_all("table.chart td.differs", "cs => cs.length")
            images = page.eval_on_selector_all("img", "imgs => imgs.map(i => i.naturalWidth)")
        finally:
            browser.close()
    assert errors == []
    assert [c[0] for c in cells] == ["path", "path:3"]
    assert [c[2:4] for c in cells] == [["almost", "almost"]] * 2
    assert marked == 4  # every measured answer differs from 'almost'
    assert len(images) == 1 and images[0] > 0


def test_cached_runs_and_reference_do_not_depend_on_which_methods_run(tmp_path):
    a = chart.measure_chart(methods=["path"], cache_dir=tmp_path, workers=1, progress=False, **TINY)
    b = chart.measure_chart(methods=["raster", "path"], cache_dir=tmp_path, workers=1, progress=False, **TINY)
    runs = len(TINY["levels"]) * TINY["replicates"]
    assert (a.sweeps["path"].computed, b.sweeps["path"].cached, b.sweeps["path"].computed) == (runs, runs, 0)
    assert b.sweeps["raster"].computed == runs and b.reference.source.startswith("cache:")
    np.testing.assert_array_equal(b.reference.value, a.reference.value)
    # the same runs (values and their cached timings) give the same row
    assert a.rows[0].csv_row() == b.rows[1].csv_row()

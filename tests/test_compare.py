"""mcvar compare: equal time, the shared cached reference, refusals, efficiency and the winner (issue 21)."""
from __future__ import annotations

import csv
import html
import math
import time

import numpy as np
import pytest

from mcvar import cli
from mcvar.compare_report import compare_report, write_compare
from mcvar.experiments import compare as cmp
from mcvar.integrators import METHODS
from mcvar.scene import load_scene

RES = 8
SECONDS = 0.15
REF_SPP = {"cornell": 32, "cornell-point": 32}


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare")
    # radiosity refuses cornell-point (no patch holds a point light): a refusal that is the scene's nature
    paths = compare_report(out, scenes="cornell,cornell-point", methods="path,direct,radiosity", seconds=SECONDS,
                           res=RES, seeds=2, seed=3, progress=False, reference_spp=REF_SPP)
    return out, paths


def test_equal_time_is_honoured_within_one_round():
    scene = load_scene("cornell")
    for seconds in (0.1, 0.3):
        tr = cmp.equal_time_render(scene, "path", seconds=seconds, res=RES, rng=np.random.SeedSequence(11))
        # the rounds stop once the time is spent: never short of it, over it by at most the last round
        assert tr.seconds >= seconds
        assert tr.seconds - seconds <= tr.max_round_seconds + 0.02
        assert tr.rounds >= 1 and tr.spp >= tr.rounds
        assert tr.image.shape == (RES, RES, 3) and np.all(np.isfinite(tr.image))


def test_equal_time_image_is_the_spp_weighted_mean_of_its_rounds(monkeypatch):
    # an exact identity: with a renderer whose round image is its spp, the combined image is
    # sum(spp_k^2) / sum(spp_k), which only the spp-weighted mean gives
    calls = []

    class R:
        def __init__(self, spp):
            self.image, self.spp, self.interrupted = np.full((RES, RES, 3), float(spp)), spp, False

    def fake(scene, *, integrator, spp, res, rng, progress, **options):
        calls.append(spp)
        time.sleep(2e-5 * spp)  # a cost per sample, so that the rounds' sizes follow the measured rate
        return R(spp)

    monkeypatch.setattr(cmp, "_render", fake)
    tr = cmp.equal_time_render(load_scene("cornell"), "path", seconds=0.05, res=RES, rng=1)
    s = np.array(calls, float)
    assert len(s) >= 3 and len(set(calls)) >= 2  # rounds of different sizes
    assert tr.spp == s.sum()
    np.testing.assert_allclose(tr.image, (s ** 2).sum() / s.sum())


def test_reference_cache_is_reused_and_invalidated(tmp_path, monkeypatch):
    real, count = cmp._render, []

    def counting(*args, **kwargs):
        count.append(kwargs["integrator"])
        return real(*args, **kwargs)

    monkeypatch.setattr(cmp, "_render", counting)
    first = cmp.scene_reference("cornell", RES, spp=8, chunks=2, cache_dir=tmp_path)
    assert len(count) == 2 and not first.cached
    second = cmp.scene_reference("cornell", RES, spp=8, chunks=2, cache_dir=tmp_path)
    assert len(count) == 2 and second.cached          # read, not rendered
    np.testing.assert_array_equal(first.value, second.value)
    assert second.noise == first.noise
    for changed in (dict(spp=16), dict(res=RES + 2), dict(seed=1), dict(method="bdpt")):
        settings = dict(spp=8, res=RES, seed=0, method=None) | changed
        n = len(count)
        ref = cmp.scene_reference("cornell", settings.pop("res"), chunks=2, cache_dir=tmp_path, **settings)
        assert not ref.cached and len(count) == n + 2, changed


def test_reference_noise_is_the_variance_of_the_chunk_mean(tmp_path, monkeypatch):
    images = [np.full((RES, RES, 3), v) for v in (1.0, 2.0, 6.0)]

    class R:
        def __init__(self, image):
            self.image, self.spp, self.interrupted = image, 1, False

    monkeypatch.setattr(cmp, "_render", lambda *a, **k: R(images.pop(0)))
    ref = cmp.scene_reference("cornell", RES, spp=3, chunks=3, cache_dir=tmp_path)
    np.testing.assert_allclose(ref.value, 3.0)
    assert ref.noise == pytest.approx(np.var([1.0, 2.0, 6.0], ddof=1) / 3)
    np.testing.assert_allclose(ref.variance, np.var([1.0, 2.0, 6.0], ddof=1) / 3)


def test_refused_method_gives_its_reason_in_csv_and_html(report):
    out, paths = report
    rows = {(r["scene"], r["method"]): r for r in _read(paths["csv"])}
    reason = rows[("cornell-point", "radiosity")]["reason"]
    with pytest.raises(ValueError) as exc:
        METHODS["radiosity"].check_scene(load_scene("cornell-point"), METHODS["radiosity"].options)
    assert reason == str(exc.value) and "point light" in reason
    assert rows[("cornell-point", "radiosity")]["efficiency"] == "nan"
    assert html.escape(reason) in paths["html"].read_text()
    assert rows[("cornell", "radiosity")]["reason"] == ""


def test_efficiency_is_one_over_mse_times_time_of_the_recorded_medians(report):
    out, paths = report
    runs = _read(paths["runs"])
    # 'reference-cornell-*' would also match cornell-point's file: the key after the scene has no '-'
    ref = {s: np.load(next(p for p in (out / ".cache").glob(f"reference-{s}-*.npz")
                           if "-" not in p.stem[len(f"reference-{s}-"):]))["value"]
           for s in ("cornell", "cornell-point")}
    images = np.load(out / "compare_images.npz")
    checked = 0
    for row in _read(paths["csv"]):
        if row["reason"]:
            continue
        mine = [r for r in runs if r["scene"] == row["scene"] and r["method"] == row["method"]]
        mse = np.median([float(r["mse"]) for r in mine])
        seconds = np.median([float(r["seconds"]) for r in mine])
        assert float(row["mse"]) == pytest.approx(mse, rel=1e-12)
        assert float(row["seconds"]) == pytest.approx(seconds, rel=1e-12)
        assert float(row["mse_x_time"]) == pytest.approx(mse * seconds, rel=1e-12)
        assert float(row["efficiency"]) == pytest.approx(1.0 / (mse * seconds), rel=1e-12)
        # seed 0's MSE recomputed from its saved image and the cached reference
        seed0 = [r for r in mine if r["seed"] == "0"][0]
        img = images[f"{row['scene']}__{row['method']}"]
        assert float(seed0["mse"]) == pytest.approx(np.mean((img - ref[row["scene"]]) ** 2), rel=1e-12)
        for r in mine:  # every seed took the equal time
            assert float(r["seconds"]) >= SECONDS
        checked += 1
    assert checked == 5


def test_winner_is_the_argmax_of_efficiency_per_column(report):
    out, paths = report
    rows = _read(paths["csv"])
    for scene in ("cornell", "cornell-point"):
        col = [r for r in rows if r["scene"] == scene and not r["reason"]]
        best = max(col, key=lambda r: float(r["efficiency"]))
        assert [r["method"] for r in col if r["winner"] == "yes"] == [best["method"]]
        assert float(best["relative_efficiency"]) == 1.0
        for r in col:
            assert float(r["relative_efficiency"]) == pytest.approx(
                float(r["efficiency"]) / float(best["efficiency"]), rel=1e-12)
            assert float(r["relative_efficiency"]) <= 1.0
    assert paths["png"].stat().st_size > 0 and "winner" in paths["html"].read_text()


def test_second_report_renders_no_reference(report, monkeypatch):
    out, _ = report
    seen = []
    real = cmp._render
    monkeypatch.setattr(cmp, "_render", lambda *a, **k: seen.append(k.get("spp")) or real(*a, **k))
    result = cmp.measure_compare(["cornell"], ["direct"], seconds=0.05, res=RES, seeds=1, seed=3,
                                 cache_dir=out / ".cache", progress=False, reference_spp=REF_SPP)
    assert result.references["cornell"].cached
    assert sum(seen) == result.cells[("cornell", "direct")].runs[0]["spp"]   # only the equal-time rounds


def test_ctrl_c_keeps_the_finished_cells(monkeypatch, tmp_path):
    real = cmp._render

    def interrupt_on_light(*args, **kwargs):
        if kwargs["integrator"] == "light":
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(cmp, "_render", interrupt_on_light)
    result = cmp.measure_compare(["cornell"], ["direct", "light", "path"], seconds=0.05, res=RES, seeds=1,
                                 cache_dir=tmp_path, progress=False, reference_spp=REF_SPP,
                                 references={"cornell": "path"})
    assert result.interrupted
    assert set(result.cells) == {("cornell", "direct")}
    paths = write_compare(result, tmp_path / "out")
    assert [r["method"] for r in _read(paths["csv"])] == ["direct"]


@pytest.mark.parametrize("kwargs, name", [
    (dict(scenes="nope"), "scenes"), (dict(methods="path,teleport"), "methods"), (dict(seconds=0), "seconds"),
    (dict(seconds=-1.0), "seconds"), (dict(seconds=math.nan), "seconds"), (dict(res=0), "res"),
    (dict(res=-4), "res"), (dict(seeds=0), "seeds")])
def test_bad_input_is_a_value_error_naming_the_argument(kwargs, name, tmp_path, monkeypatch):
    monkeypatch.setattr(cmp, "_render", lambda *a, **k: pytest.fail("rendered before validating"))
    args = dict(scenes="cornell", methods="path", seconds=1.0, res=8, seeds=1) | kwargs
    with pytest.raises(ValueError, match=name):
        cmp.measure_compare(args.pop("scenes"), args.pop("methods"), progress=False, **args)
    with pytest.raises(ValueError, match=name):
        compare_report(tmp_path / "o", progress=False, **(dict(scenes="cornell", methods="path", seconds=1.0,
                                                                 res=8, seeds=1) | kwargs))


@pytest.mark.parametrize("argv, name", [
    (["--scenes", "nope"], "scenes"), (["--methods", "teleport"], "methods"), (["--seconds", "0"], "seconds"),
    (["--res", "0"], "res")])
def test_cli_bad_input_is_one_line_and_exit_2(argv, name, capsys, tmp_path):
    assert cli.main(["compare", "--quiet", "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("mcvar compare: error:") and name in err


def test_cli_help_lists_every_registered_method(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["compare", "--help"])
    assert exc.value.code == 0
    compact = "".join(capsys.readouterr().out.split())  # argparse wraps (and breaks at hyphens)
    listed = compact.split("registeredmethods:")[1].split("(default")[0].split(",")
    assert listed == list(METHODS)
    scenes = compact.split("--scenesSCENEScomma-separatedscenes:")[1].split("(default")[0].split(",")
    assert scenes == list(cmp.compare_scenes())


def test_region_mse_is_measured_inside_the_region_only(tmp_path):
    region = (0.5, 1.0, 0.0, 0.5)   # the lower left quarter
    result = cmp.measure_compare(["cornell"], ["direct"], seconds=0.05, res=RES, seeds=1, cache_dir=tmp_path,
                                 progress=False, reference_spp=REF_SPP, regions={"cornell": region})
    cell, ref = result.cells[("cornell", "direct")], result.references["cornell"].value
    half = RES // 2
    crop = (cell.image - ref)[half:, :half]
    assert cell.runs[0]["mse"] == pytest.approx(np.mean(crop ** 2), rel=1e-12)
    assert cell.runs[0]["mse"] != pytest.approx(np.mean((cell.image - ref) ** 2), rel=1e-3)
    assert result.rows()[0]["region"] == "rows 0.50-1.00, columns 0.00-0.50"
    var = result.references["cornell"].variance
    assert result.rows()[0]["reference_noise"] == pytest.approx(var[half:, :half].mean(), rel=1e-12)
    with pytest.raises(ValueError, match="regions"):
        cmp.measure_compare(["cornell"], ["direct"], seconds=0.05, res=RES, progress=False,
                            regions={"cornell": (0.5, 0.2, 0.0, 1.0)})


def test_point_light_pair_path_bsdf_is_black_and_pairs_go_to_the_page(tmp_path):
    pairs = cmp.measure_pairs(seconds=0.05, res=RES, seeds=1, cache_dir=tmp_path, progress=False,
                              pairs=["point light", "caustic"],
                              reference_spp={"cornell-point": 64, "cornell-spheres": 8})
    point = pairs["point light"]
    assert point.methods == ("path", "path_bsdf", "light")
    # BSDF sampling alone never hits a point light: exactly black, where path tracing is not
    assert np.all(point.cells[("cornell-point", "path_bsdf")].image == 0)
    assert point.cells[("cornell-point", "path_bsdf")].mean_ratio == 0.0
    # path tracing reaches it through next-event estimation: most pixels see a lit surface
    assert np.count_nonzero(point.cells[("cornell-point", "path")].image.sum(axis=-1)) > RES * RES // 2
    assert pairs["caustic"].rows()[0]["region"] == cmp._region_text(cmp.CAUSTIC_REGION)
    with pytest.raises(ValueError, match="pairs"):
        cmp.measure_pairs(seconds=0.05, pairs=["teleport"])
    paths = write_compare(point, tmp_path / "out", pairs=pairs)
    rows = _read(paths["pairs"])
    assert {(r["pair"], r["method"]) for r in rows} == {("point light", "path"), ("point light", "path_bsdf"),
                                                        ("point light", "light"), ("caustic", "path"),
                                                        ("caustic", "sppm")}
    assert "BSDF sampling alone" in paths["html"].read_text()

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
from mcvar.experiments import compare_args
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

    monkeypatch.setattr(compare_args, "_render", fake)
    tr = cmp.equal_time_render(load_scene("cornell"), "path", seconds=0.05, res=RES, rng=1)
    s = np.array(calls, float)
    assert len(s) >= 3 and len(set(calls)) >= 2  # rounds of different sizes
    assert tr.spp == s.sum()
    np.testing.assert_allclose(tr.image, (s ** 2).sum() / s.sum())


def test_reference_cache_is_reused_and_invalidated(tmp_path, monkeypatch):
    real, count = compare_args._render, []

    def counting(*args, **kwargs):
        count.append(kwargs["integrator"])
        return real(*args, **kwargs)

    monkeypatch.setattr(compare_args, "_render", counting)
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

    monkeypatch.setattr(compare_args, "_render", lambda *a, **k: R(images.pop(0)))
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
    real = compare_args._render
    monkeypatch.setattr(compare_args, "_render", lambda *a, **k: seen.append(k.get("spp")) or real(*a, **k))
    result = cmp.measure_compare(["cornell"], ["direct"], seconds=0.05, res=RES, seeds=1, seed=3,
                                 cache_dir=out / ".cache", progress=False, reference_spp=REF_SPP)
    assert result.references["cornell"].cached
    assert sum(seen) == result.cells[("cornell", "direct")].runs[0]["spp"]   # only the equal-time rounds


def test_ctrl_c_keeps_the_finished_cells(monkeypatch, tmp_path):
    real = compare_args._render

    def interrupt_on_light(*args, **kwargs):
        if kwargs["integrator"] == "light":
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(compare_args, "_render", interrupt_on_light)
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
    monkeypatch.setattr(compare_args, "_render", lambda *a, **k: pytest.fail("rendered before validating"))
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
                              reference_spp={"cornell-point": 64, "cornell-caustic": 8})
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


# --------------------------------------------------------------------------
# the default matrix, the new pairs (issue 21)
# --------------------------------------------------------------------------

def test_default_matrix_is_the_issue_scenes_and_every_transport_method(monkeypatch):
    from dataclasses import replace

    st = cmp.compare_settings()
    assert tuple(st.scenes) == ("cornell", "cornell-point", "cornell-door", "cornell-caustic", "veach-mis")
    methods = cmp.default_methods()
    # every registered method that estimates light transport, none of the AOVs / rasterization
    assert set(methods) == {m for m, e in METHODS.items() if e.kind != "first_hit" or e.prepare is not None}
    assert {"albedo", "normal", "depth", "raster", "position"}.isdisjoint(methods)
    assert methods[:3] == ("path", "path_bsdf", "direct")
    # a method registered later (a Metropolis method, say) joins the matrix and the Metropolis pair
    toy = replace(METHODS["pssmlt"], name="toy_mlt")
    monkeypatch.setitem(METHODS, "toy_mlt", toy)
    assert cmp.default_methods()[-1] == "toy_mlt"
    from mcvar.experiments import slide_pairs
    assert "toy_mlt" in slide_pairs.metropolis_methods()
    assert "toy_mlt" in slide_pairs._pair_methods("metropolis", cmp.PAIRS["metropolis"][1])


def test_cells_of_the_new_scenes_that_radiosity_cannot_render_carry_its_reason(tmp_path):
    result = cmp.measure_compare(["cornell-caustic", "veach-mis"], ["radiosity"], seconds=0.05, res=RES, seeds=1,
                                 cache_dir=tmp_path, progress=False,
                                 reference_spp={"cornell-caustic": 8, "veach-mis": 8})
    entry = METHODS["radiosity"]
    for scene in ("cornell-caustic", "veach-mis"):
        cell = result.cells[(scene, "radiosity")]
        assert not cell.rendered and cell.runs == ()
        with pytest.raises(ValueError) as exc:
            entry.check_scene(load_scene(scene), entry.resolve_options(cmp._options("radiosity")))
        assert cell.reason == str(exc.value) and "Lambertian" in cell.reason
        assert result.winner(scene) is None


def test_strategy_grid_sums_to_the_bdpt_image_exactly():
    grid = cmp.measure_strategy_grid("cornell-caustic", res=RES, spp=2, renders=2, seed=5)
    total = sum(grid.strategies.values())
    np.testing.assert_allclose(total, grid.image, rtol=1e-12, atol=1e-15)
    assert grid.image.mean() > 0
    # the shares are each strategy's part of one sum: they add to 1, in the image and in the caustic
    assert sum(r["share"] for r in grid.rows) == pytest.approx(1.0, rel=1e-12)
    assert sum(r["region_share"] for r in grid.rows) == pytest.approx(1.0, rel=1e-12)
    # every strategy of depth <= 4 that the caustic scene can produce is kept (s light, t camera vertices)
    assert set(grid.strategies) <= {(s, t) for s in range(5) for t in range(1, 6) if 2 <= s + t <= 5}
    assert (4, 1) in grid.strategies and (0, 5) in grid.strategies
    with pytest.raises(ValueError, match="max_depth"):
        cmp.measure_strategy_grid(res=RES, spp=1, renders=2, max_depth=5)
    with pytest.raises(ValueError, match="renders"):
        cmp.measure_strategy_grid(res=RES, spp=1, renders=1)
    # the variance of a strategy that renders nothing is 0; of the whole image, positive
    assert all(r["region_variance"] == 0.0 for r in grid.rows if r["energy"] == 0.0)


def test_strategy_grid_image_is_the_plain_render_of_the_same_streams():
    # asking for the strategies changes no draw: the grid's image is plain BDPT on the same streams
    grid = cmp.measure_strategy_grid("cornell-caustic", res=RES, spp=2, renders=2, seed=7)
    sc = load_scene("cornell-caustic")
    images = [compare_args._render(sc, integrator="bdpt", spp=2, res=RES, max_depth=4, rng=stream,
                                   progress=False).image
              for stream in cmp._seed_sequence("strategies", "cornell-caustic", 7).spawn(2)]
    np.testing.assert_allclose(grid.image, np.mean(images, axis=0), rtol=1e-12, atol=1e-15)


def test_radiosity_second_view_from_the_solve_equals_a_fresh_solve_of_that_view(tmp_path):
    from dataclasses import replace
    from functools import partial

    from mcvar.experiments.equal_time import _prepared

    views = cmp.radiosity_views("cornell", res=RES, seed=2, cache_dir=tmp_path, reference_spp=8)
    sc = load_scene("cornell")
    sc2 = replace(sc, camera=views["camera"])
    entry = METHODS["radiosity"]
    opts = entry.resolve_options(cmp._options("radiosity"))
    # solved afresh *from the second camera's scene*: the same solve, so the same image of that view
    solve = entry.prepare(sc2, opts, np.random.default_rng(cmp._seed_sequence("radiosity", "cornell", 2)))
    fresh = compare_args._render(sc2, integrator=replace(entry, prepare=partial(_prepared, solve)), spp=4, res=RES,
                                 rng=cmp._seed_sequence("view2", 2))
    np.testing.assert_array_equal(fresh.image, views["images"][1])
    assert not np.array_equal(views["images"][0], views["images"][1])      # a different view indeed
    assert 0 < views["view2_seconds"] < views["full_seconds"]
    assert views["fraction"] == pytest.approx(views["view2_seconds"] / views["full_seconds"], rel=1e-12)
    assert views["mse2"] == pytest.approx(np.mean((views["images"][1] - views["references"][1]) ** 2), rel=1e-12)


def test_forward_tracing_without_the_camera_connection_never_hits_the_pinhole():
    f = cmp.forward_pinhole_hits("cornell-point", n_paths=4096, seed=1, radii=(10.0, 100.0, 1000.0))
    assert f["hits"] == 0 and f["energy_fraction"] == 0.0
    assert f["rays"] > f["paths"] and f["escaping"] > 0       # rays leave the box, towards the camera too
    assert f["closest"] > 0
    within = list(f["within"].values())
    assert within == sorted(within) and within[-1] > 0       # more rays pass within a larger radius


def test_distance_of_the_pinhole_from_rays_is_the_brute_force_minimum():
    from mcvar.experiments.slide_pairs import _distance_to_rays

    rng = np.random.default_rng(4)
    a, c = rng.normal(size=(50, 3)), rng.normal(size=3)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = rng.uniform(0.1, 3.0, 50)
    u = np.linspace(0, 1, 20001)
    brute = np.array([np.linalg.norm(a[i] + d[i] * (length[i] * u)[:, None] - c, axis=1).min() for i in range(50)])
    np.testing.assert_allclose(_distance_to_rays(c, a, d, length), brute, rtol=0, atol=2e-4)
    # a ray aimed at the pinhole passes through it
    towards = (c - a[0]) / np.linalg.norm(c - a[0])
    assert _distance_to_rays(c, a[:1], towards[None], np.array([np.inf]))[0] < 1e-12


def test_the_pairs_write_their_files_and_sections(tmp_path):
    pairs = cmp.measure_pairs(seconds=0.05, res=RES, seeds=1, cache_dir=tmp_path, progress=False,
                              pairs=["bdpt caustic"], reference_spp={"cornell-caustic": 8})
    grid = cmp.measure_strategy_grid(res=RES, spp=1, renders=2)
    forward = cmp.forward_pinhole_hits(n_paths=512)
    paths = write_compare(pairs["bdpt caustic"], tmp_path / "out", pairs=pairs, grid=grid, forward=forward)
    rows = _read(paths["strategies"])
    assert [(int(r["s"]), int(r["t"])) for r in rows] == [(r["s"], r["t"]) for r in grid.rows]
    assert float(rows[0]["share"]) == pytest.approx(grid.rows[0]["share"], rel=1e-12)
    assert paths["strategies_png"].stat().st_size > 0
    assert {r["quantity"]: r["value"] for r in _read(paths["forward"])}["hits"] == "0"
    page = paths["html"].read_text()
    assert "strategies on cornell-caustic" in page and "pass through the pinhole" in page
    assert {r["method"] for r in _read(paths["pairs"])} == {"path", "bdpt"}

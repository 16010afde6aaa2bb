"""``mcvar render`` renders with the most efficient unbiased configuration by
default (adaptive Sobol'), and ``--uniform --sampler random`` gives the
previous default's image exactly."""
import numpy as np

from mcvar.adaptive import render_adaptive
from mcvar.cli import main
from mcvar.integrators import render
from mcvar.scene import load_scene


def test_render_default_is_adaptive_sobol_and_uniform_is_the_previous_default(tmp_path, capsys):
    scene = load_scene("cornell")
    out = tmp_path / "a.npy"
    assert main(["render", "cornell", "--res", "8", "--spp", "16", "--seed", "3", "--quiet", "--out", str(out)]) == 0
    expect = render_adaptive(scene, spp=16, res=8, sampler="sobol", rng=3).image
    assert np.array_equal(np.load(out), expect.astype(np.float32))          # .npy stores float32
    out2 = tmp_path / "b.npy"
    assert main(["render", "cornell", "--res", "8", "--spp", "16", "--seed", "3", "--quiet", "--uniform",
                 "--sampler", "random", "--out", str(out2)]) == 0
    before = render(scene, spp=16, res=8, sampler="random", rng=3).image
    assert np.array_equal(np.load(out2), before.astype(np.float32))
    assert not np.array_equal(expect, before)
    # first-hit integrators and tiny spp stay uniform
    out3 = tmp_path / "c.npy"
    assert main(["render", "cornell", "--res", "8", "--spp", "4", "--seed", "3", "--quiet",
                 "--out", str(out3)]) == 0
    assert np.array_equal(np.load(out3), render(scene, spp=4, res=8, sampler="sobol", rng=3).image.astype(np.float32))
    capsys.readouterr()


def test_demo_adds_the_best_configuration_image(tmp_path, monkeypatch, capsys):
    """``mcvar demo`` writes cornell-best.png (adaptive Sobol) after its report;
    ``--no-best`` is the previous behaviour (the report alone). The report
    itself is replaced by a stub here: it has its own tests."""
    import mcvar.demo

    monkeypatch.setattr(mcvar.demo, "demo", lambda out, progress=True: {})
    assert main(["demo", "--out", str(tmp_path / "a"), "--quiet", "--no-best"]) == 0
    assert not (tmp_path / "a" / "cornell-best.png").exists()
    assert main(["demo", "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert (tmp_path / "b" / "cornell-best.png").stat().st_size > 0
    assert "adaptive Sobol" in capsys.readouterr().out


def test_render_default_spreads_adaptive_renders_over_both_cores(tmp_path, monkeypatch, capsys):
    """Adaptive renders default to two processes (the caller and one more;
    docs/performance.md), ``--workers`` overrides it, ``--uniform`` keeps one."""
    import os

    import mcvar.adaptive
    import mcvar.integrators

    seen = []
    adaptive, uniform = mcvar.adaptive.render_adaptive, mcvar.integrators.render
    monkeypatch.setattr(mcvar.adaptive, "render_adaptive", lambda *a, **k: seen.append(k["workers"]) or adaptive(*a, **k))
    monkeypatch.setattr(mcvar.integrators, "render", lambda *a, **k: seen.append(k["workers"]) or uniform(*a, **k))
    base = ["render", "cornell", "--res", "4", "--spp", "16", "--quiet", "--out", str(tmp_path / "a.npy")]
    for extra in ([], ["--workers", "1"], ["--uniform"]):
        assert main(base + extra) == 0
    assert seen == [min(2, os.cpu_count() or 1), 1, 1]
    capsys.readouterr()


def test_render_estimator_flags_reach_both_renderers(tmp_path, capsys):
    """``--visible-lights``, ``--rr-threshold`` and ``--rr-depth`` give the
    library's images for the same options: the adaptive default's previous
    configuration (sampled lights, pbrt's roulette from 7 segments) and a
    uniform render with the exact light."""
    scene = load_scene("cornell")
    out = tmp_path / "a.npy"
    assert main(["render", "cornell", "--res", "8", "--spp", "16", "--seed", "3", "--quiet",
                 "--visible-lights", "sampled", "--rr-threshold", "1", "--rr-depth", "7", "--out", str(out)]) == 0
    expect = render_adaptive(scene, spp=16, res=8, sampler="sobol", rng=3, visible_lights="sampled",
                             rr_threshold=1.0, rr_depth=7).image
    assert np.array_equal(np.load(out), expect.astype(np.float32))
    assert not np.array_equal(expect, render_adaptive(scene, spp=16, res=8, sampler="sobol", rng=3).image)
    out2 = tmp_path / "b.npy"
    assert main(["render", "cornell", "--res", "8", "--spp", "16", "--seed", "3", "--quiet", "--uniform",
                 "--visible-lights", "exact", "--out", str(out2)]) == 0
    uniform = render(scene, spp=16, res=8, sampler="sobol", rng=3, visible_lights="exact").image
    assert np.array_equal(np.load(out2), uniform.astype(np.float32))
    assert main(["render", "cornell", "--res", "8", "--spp", "16", "--quiet", "--rr-threshold", "2",
                 "--out", str(tmp_path / "c.npy")]) == 2
    capsys.readouterr()

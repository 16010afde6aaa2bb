"""The recipes of docs/integrators.md ('Adding a method') and docs/samplers.md ('Adding
a sampler') followed at test time: a toy method and a toy sampler are registered into
the live registries (and removed afterwards), and ``render``, the CLI and the chart
pick them up with no other edit."""
import math

import numpy as np
import pytest

pytest.importorskip("mcvar.integrators")

from mcvar import samplers  # noqa: E402
from mcvar.cli import main  # noqa: E402
from mcvar.experiments import chart  # noqa: E402
from mcvar.integrators import METHODS, Method, register, render  # noqa: E402
from mcvar.integrators.film import camera_result  # noqa: E402
from mcvar.integrators.knobs import spp_knob  # noqa: E402
from mcvar.integrators.stream import camera_rays  # noqa: E402
from mcvar.scene import load_scene  # noqa: E402

# ---------------------------------------------------------------- the toy method (one module's worth)


def run_emitted_batch(job):
    """Emitted radiance seen directly: the first hit's ``Le`` toward the camera."""
    n = job.n_pixels * job.spp
    _, o, d, _ = camera_rays(job)
    o = np.ascontiguousarray(o)
    hit = job.tracer.intersect(o, d)
    rows = np.flatnonzero(hit.prim >= 0)
    out = np.zeros((n, 3))
    if rows.size:
        prim, p = hit.prim[rows], o[rows] + hit.t[rows, None] * d[rows]
        out[rows] = job.scene.emission(prim, p, job.tracer.normals(prim, p), d[rows])
    return camera_result(job, out, n, "toy_emitted")


TOY_METHOD = Method("toy_emitted", "camera", run_emitted_batch, "emitted light seen directly (a toy)",
                    uses_max_depth=False, lecture=("no", "no"), knob=spp_knob("toy_emitted"),
                    theory=("no", "no", "no bounce at all: only the lights themselves"))

# ---------------------------------------------------------------- the toy sampler (one function, one record)

_PLASTIC = 1.324717957244746   # x^3 = x + 1: the R2 sequence's generator (Roberts 2018)


def r2(n, *, rng=None):
    """Roberts' R2 sequence ``frac(s + i (1/g, 1/g^2))``, with a random start ``s``."""
    s = np.random.default_rng(rng).random(2)
    i = np.arange(n)[:, None]
    return np.minimum(np.mod(s + i * np.array([1 / _PLASTIC, 1 / _PLASTIC ** 2]), 1.0), samplers.ONE_MINUS_EPS)


TOY_SAMPLER = samplers.Sampler("toy_r2", r2, -1.0, "a Kronecker sequence: O(log n / n)", words_per_coord=2)


@pytest.fixture
def toys():
    register(TOY_METHOD)
    samplers.register_sampler(TOY_SAMPLER)
    try:
        yield
    finally:
        METHODS.pop("toy_emitted", None)
        samplers.SAMPLERS.pop("toy_r2", None)


def test_the_toys_are_gone_outside_the_fixture():
    assert "toy_emitted" not in METHODS and "toy_r2" not in samplers.SAMPLERS


def test_render_runs_the_toy_method_with_the_toy_sampler(toys):
    """Identity: emitted light seen directly is path tracing stopped at depth 1 (the same
    camera rays from the same sample columns), so the images agree to rounding."""
    scene = load_scene("cornell")
    toy = render(scene, integrator="toy_emitted", sampler="toy_r2", spp=16, res=8, rng=5, progress=False,
                 workers=1)
    path1 = render(scene, integrator="path", sampler="toy_r2", spp=16, res=8, rng=5, max_depth=1,
                   progress=False, workers=1)
    assert toy.image.shape == (8, 8, 3) and toy.image.max() > 0
    np.testing.assert_allclose(toy.image, path1.image, rtol=1e-6, atol=1e-9)
    # the toy sampler really feeds the camera: another sampler gives another image
    other = render(scene, integrator="toy_emitted", sampler="random", spp=16, res=8, rng=5, progress=False,
                   workers=1)
    assert not np.array_equal(other.image, toy.image)


def test_the_toy_sampler_is_a_sampler_everywhere(toys):
    pts = samplers.get_sampler("toy_r2")(64, rng=3)
    assert pts.shape == (64, 2) and pts.min() >= 0 and pts.max() < 1
    sets = samplers.pixel_samples("toy_r2", 5, 16, dim=4, rng=2)
    assert sets.shape == (5, 16, 4) and np.all((sets >= 0) & (sets < 1))
    # the samplers' sweep takes it by name: at n = 1024 R2's star discrepancy (~log n / n) is
    # below random's (~n^-1/2) by far more than 5 standard errors of the difference
    from mcvar.sampler_report import discrepancy_sweep

    rows = {r["sampler"]: r for r in discrepancy_sweep([1024], names=["toy_r2", "random"], replicates=8,
                                                       rng=1)}
    gap = rows["random"]["star"] - rows["toy_r2"]["star"]
    assert gap > 5 * math.hypot(rows["random"]["star_se"], rows["toy_r2"]["star_se"]), rows
    with pytest.raises(ValueError, match="already registered"):
        samplers.register_sampler(TOY_SAMPLER)


def test_the_cli_lists_and_renders_the_toys(toys, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "toy_emitted" in shown and "toy_r2" in shown
    out = tmp_path / "toy.npy"
    assert main(["render", "cornell", "--integrator", "toy_emitted", "--sampler", "toy_r2", "--spp", "4",
                 "--res", "8", "--uniform", "--workers", "1", "--quiet", "--out", str(out)]) == 0
    image = np.load(out)
    expected = render(load_scene("cornell"), integrator="toy_emitted", sampler="toy_r2", spp=4, res=8,
                      rng=1, progress=False, workers=1).image
    np.testing.assert_array_equal(image, expected)      # --seed 1 is the CLI's default


def test_the_chart_measures_the_toy_method_from_its_record(toys):
    assert chart.chart_methods()[-1] == "toy_emitted"   # a knob and a lecture claim: a row of its own
    result = chart.measure_chart(methods=["toy_emitted"], res=4, replicates=3, levels=(1, 4),
                                 reference_spp=16, reference_chunks=2, workers=1, progress=False)
    (row,) = result.rows
    assert row.method == "toy_emitted" and (row.lecture_consistent, row.lecture_unbiased) == ("no", "no")
    assert row.knob == "spp" and row.levels == (1, 4)
    assert math.isfinite(row.mse_x_time) and row.mse_x_time > 0
    # the toy misses every bounce: its image is far below the path-traced reference
    mean = float(np.mean(result.sweeps["toy_emitted"].values[("toy_emitted", "random", 4)]))
    assert mean < 0.5 * float(np.mean(result.reference.value))

"""Reliability of the newer parts (issue 24): bad input refused before any work,
with the exact error type and the argument's name in the message, and the
identities between functions that compute one quantity.

Classes (the issue's list): work that can never fit is refused before anything
is allocated or traced (one memory rule, :func:`mcvar._validation.check_budget`);
booleans checked as booleans; hand-built scenes validated field by field;
errors that name their cause (library and CLI); domains that overflow; graders
that check their own arguments. Each refusal test also makes the work it
refuses impossible to start (the tracer or the target raises a sentinel), so a
check that came after the work began would fail the test.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import mcvar._validation as V
from mcvar import mcmc
from mcvar import metrics as M
from mcvar.bsdf import Lambertian
from mcvar.geometry import polygon_pixel_coverage
from mcvar.integrators import METHODS, render
from mcvar.integrators import photon as PH
from mcvar.integrators import radiosity as RA
from mcvar.integrators.sppm import sppm
from mcvar.piecewise import PiecewiseConstant1D, PiecewiseConstant2D
from mcvar.scene import Camera, Scene, load_scene
from mcvar.testing import grade as G

SEED = 24
HUGE = 2 ** 40


class _Started(AssertionError):
    """Raised by a patched tracer or target: the work was started."""


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


@pytest.fixture
def no_tracing(monkeypatch):
    """Any ray traced raises _Started: a refusal must come before the first ray."""
    def boom(*args, **kwargs):
        raise _Started("work started before the check")
    from mcvar.tracer import Tracer
    monkeypatch.setattr(Tracer, "intersect", boom)
    monkeypatch.setattr(Tracer, "occluded", boom, raising=False)


# --------------------------------------------------------------------------
# 1. Work that can never fit: the one rule

def test_check_budget_names_option_need_and_fit():
    with pytest.raises(ValueError) as exc:
        V.check_budget("photons", 1000, 1000 * 180.0, per_unit=180.0, budget=18_000)
    msg = str(exc.value)
    assert "photons=1000" in msg and "176 KiB" in msg and "17.6 KiB" in msg and "at most photons=100 fits" in msg
    V.check_budget("photons", 100, 100 * 180.0, per_unit=180.0, budget=18_000)   # exactly at the budget: fine
    with pytest.raises(ValueError, match="x=nan"):
        V.check_budget("x", float("nan"), float("nan"))                            # NaN never fits


def test_budget_is_read_at_call_time(monkeypatch):
    monkeypatch.setattr(V, "MEMORY_BUDGET", 1000)
    with pytest.raises(ValueError, match="budget of 1e\\+03 bytes"):
        V.check_budget("n", 2, 2000.0)
    monkeypatch.setattr(V, "MEMORY_BUDGET", 4000)
    V.check_budget("n", 2, 2000.0)


@pytest.mark.parametrize("integrator", ["photon", "sppm"])
def test_photons_that_cannot_fit_are_refused_before_tracing(cornell, integrator, no_tracing):
    with pytest.raises(ValueError, match=r"photons=1099511627776 needs about 180 TiB.*at most photons=23860929"):
        render(cornell, integrator=integrator, spp=1, res=2, photons=HUGE)


def test_photon_functions_refuse_too_many_photons(cornell, no_tracing):
    with pytest.raises(ValueError, match="n_photons=1099511627776 needs"):
        PH.build_photon_map(cornell, HUGE)
    with pytest.raises(ValueError, match="photons_per_iteration=1099511627776 needs"):
        sppm(cornell, res=2, iterations=1, photons_per_iteration=HUGE)


def test_photon_k_nearest_refused_when_its_arrays_cannot_fit(cornell, no_tracing):
    with pytest.raises(ValueError, match=r"k=1048576 needs about 800 GiB.*at most k=5242 fits"):
        render(cornell, integrator="photon", spp=1, res=2, photons=1 << 20, k=1 << 20)


def test_photon_budget_matches_the_maps_own_bytes(cornell):
    """Identity: the budget's bytes per stored photon (74) is what PhotonMap.nbytes counts."""
    pm = PH.build_photon_map(cornell, 2000, rng=SEED)
    assert pm.photons.n > 0
    assert pm.nbytes == 74 * pm.photons.n
    assert PH.BYTES_PER_PHOTON == 2 * 74 + 32


def test_pssmlt_bootstrap_and_chains_refused_before_tracing(cornell, no_tracing):
    with pytest.raises(ValueError, match=r"n_bootstrap=1099511627776 needs about 296 TiB.*at most n_bootstrap="):
        render(cornell, integrator="pssmlt", spp=1, res=2, n_bootstrap=HUGE)
    with pytest.raises(ValueError, match=r"chains=1099511627776 with state_depth=6 needs .*at most chains="):
        render(cornell, integrator="pssmlt", spp=1, res=2, chains=HUGE)


def test_metropolis_refuses_what_cannot_fit_before_calling_f():
    def f(u):
        raise _Started("f called before the check")
    with pytest.raises(ValueError, match="n_bootstrap=1099511627776 needs about 16 TiB"):
        mcmc.metropolis(f, 1, 10, n_bootstrap=HUGE)
    with pytest.raises(ValueError, match="chains=1099511627776 with dim=1 needs"):
        mcmc.metropolis(f, 1, 10, chains=HUGE)
    with pytest.raises(ValueError, match=r"thin=1 needs about .*\(1099511627776 kept steps"):
        mcmc.metropolis(f, 1, HUGE, thin=1)
    with pytest.raises(ValueError, match="n_bootstrap=1099511627776 needs"):
        mcmc.image_walk(np.ones((2, 2)), 10, n_bootstrap=HUGE)


def test_metropolis_bootstrap_in_chunks_is_the_same_chain(monkeypatch):
    """Identity: evaluating the bootstrap candidates in chunks changes no number
    (f draws nothing from the stream; the candidates are drawn at once)."""
    f = lambda u: 1.0 + np.cos(2 * np.pi * u[:, 0]) * np.sin(np.pi * u[:, 1])
    whole = mcmc.metropolis(f, 2, 50, chains=8, n_bootstrap=5000, rng=SEED)
    monkeypatch.setattr(mcmc, "BOOTSTRAP_CHUNK", 777)
    calls = []
    chunked = mcmc.metropolis(lambda u: calls.append(u.shape[0]) or f(u), 2, 50, chains=8, n_bootstrap=5000,
                              rng=SEED)
    assert max(calls) <= 777 and sum(calls[:7]) == 5000       # 7 chunks, then one call per step
    np.testing.assert_array_equal(whole.samples, chunked.samples)
    assert whole.b.mean == chunked.b.mean


def test_radiosity_patches_refused_before_meshing(cornell, no_tracing):
    n = RA.patch_count(cornell, 1e-3)
    assert n > 10 ** 12
    with pytest.raises(ValueError, match=r"patch_size=0.001 needs about 3.62 PiB .*7950305872386 patches"):
        render(cornell, integrator="radiosity", spp=1, res=2, patch_size=1e-3)
    with pytest.raises(ValueError, match="patch_size=0.001 needs"):
        RA.radiosity(cornell, patch_size=1e-3)
    with pytest.raises(ValueError, match="patch_size=0.001 needs"):
        RA.mesh_patches(cornell, 1e-3)


def test_patch_count_is_the_meshes_count(cornell):
    """Identity: the budget's patch count is the number of patches mesh_patches makes."""
    for size in (280.0, 100.0, 37.5):
        assert RA.patch_count(cornell, size) == RA.mesh_patches(cornell, size).n


def test_radiosity_counts_budget_names_emitter_rays(cornell, monkeypatch, no_tracing):
    monkeypatch.setattr(V, "MEMORY_BUDGET", 2 ** 20)
    with pytest.raises(ValueError, match="emitter_rays=1099511627776 needs"):
        render(cornell, integrator="radiosity", spp=1, res=2, patch_size=140.0, emitter_rays=HUGE)
    with pytest.raises(ValueError, match="rays_per_side=4096 on the patches of patch_size=70.0 needs"):
        RA.radiosity(cornell, patch_size=70.0, rays_per_side=4096, emitter_rays=8)


def _closed_box(albedo=0.5, le=2.0):
    """A closed cube, inward faces, its top face emitting: every ray hits a patch."""
    c = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = []
    for a, b, cc, d in faces:
        tris += [(c[a], c[b], c[cc]), (c[a], c[cc], c[d])]
    tris = np.array(tris)
    centre = np.full(3, 0.5)
    for t in tris:                                    # normals inwards
        n = np.cross(t[1] - t[0], t[2] - t[0])
        if np.dot(n, centre - t[0]) < 0:
            t[[1, 2]] = t[[2, 1]]
    top = np.flatnonzero(np.all(tris[:, :, 1] == 1.0, axis=1))
    emission = np.zeros((12, 3))
    emission[top] = le
    return Scene(name="closed-box", triangles=tris, sphere_centers=np.zeros((0, 3)), sphere_radii=np.zeros(0),
                 prim_material=np.zeros(12, int), prim_emission=emission, prim_two_sided_emission=np.zeros(12, bool),
                 prim_light=np.full(12, -1), prim_group=np.zeros(12, int), materials=(Lambertian(albedo),),
                 material_names=("white",), light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
                 light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
                 camera=Camera(position=(0.5, 0.5, 0.1), look_at=(0.5, 0.5, 1.0), up=(0.0, 1.0, 0.0), fov_deg=60.0))


def test_emitter_rays_are_chunked_within_a_side(monkeypatch):
    """A side with more rays than RAYS_PER_CHUNK is split; exact identities of
    the closed box hold whatever the split: an emitting side's emission is
    pi Le (accumulated over the pieces of its split), and the combined matrix is
    reciprocal (A_i F_ij = A_j F_ji); the progress reports every ray once, in
    chunks of at most RAYS_PER_CHUNK."""
    scene = _closed_box()
    patches = RA.mesh_patches(scene, 0.5)
    monkeypatch.setattr(RA, "RAYS_PER_CHUNK", 1000)
    chunks = []
    from mcvar.tracer import Tracer
    ff = RA.form_factors(scene, patches, rays_per_side=64, emitter_rays=30_000, rng=SEED,
                         tracer=Tracer(scene, dtype="float64"), progress=lambda done, total: chunks.append(done))
    assert np.all(np.diff([0] + chunks) <= 1000) and chunks[-1] == ff.rays == ff.rays_per_side.sum()
    assert ff.rays_per_side.max() > 1000                      # some side was split
    row = np.asarray(ff.counts.sum(axis=1)).ravel()
    # inner sides: every ray lands but for the few that start within the tracer's epsilon of a corner
    assert np.all(row[0::2] <= ff.rays_per_side[0::2]) and row[0::2].sum() >= 0.999 * ff.rays_per_side[0::2].sum()
    np.testing.assert_array_equal(row[1::2], 0)                        # outer sides: every ray escapes
    emitting = ff.rays_per_side > 64
    np.testing.assert_allclose(ff.emission[emitting], np.pi * 2.0, rtol=1e-12)
    assert np.all(ff.emission[~emitting] == 0.0)
    g = (ff.area[:, None] * ff.matrix.toarray())
    np.testing.assert_allclose(g, g.T, rtol=1e-12, atol=0)


def test_radiosity_unsplit_chunks_are_unchanged():
    """Chunks of whole sides draw exactly as before the within-side split
    (the same rays, the same counts) when no side exceeds RAYS_PER_CHUNK."""
    scene = _closed_box()
    patches = RA.mesh_patches(scene, 0.5)
    a = RA.form_factors(scene, patches, rays_per_side=64, emitter_rays=256, rng=SEED)
    b = RA.form_factors(scene, patches, rays_per_side=64, emitter_rays=256, rng=SEED)
    assert a.rays_per_side.max() <= RA.RAYS_PER_CHUNK
    assert (a.counts != b.counts).nnz == 0


# --------------------------------------------------------------------------
# 2. Booleans checked as booleans

@pytest.mark.parametrize("option", ["mis", "strategies"])
@pytest.mark.parametrize("value", ["no", "False", 0, 1, None, 1.0])
def test_bdpt_booleans_are_booleans(cornell, option, value, no_tracing):
    with pytest.raises(TypeError, match=f"{option} must be a bool"):
        render(cornell, integrator="bdpt", spp=1, res=2, **{option: value})


def test_numpy_bool_is_a_boolean(cornell):
    a = render(cornell, integrator="bdpt", spp=1, res=4, rng=SEED, mis=np.False_)
    b = render(cornell, integrator="bdpt", spp=1, res=4, rng=SEED, mis=False)
    np.testing.assert_array_equal(a.image, b.image)


def test_other_booleans_are_booleans(cornell):
    from mcvar import discrepancy as D
    from mcvar.tracer import Tracer
    with pytest.raises(TypeError, match="bootstrap must be a bool"):
        render(cornell, integrator="pssmlt", spp=1, res=2, bootstrap="no")
    with pytest.raises(TypeError, match="squared must be a bool"):
        D.l2_star(np.full((4, 2), 0.5), squared="no")
    with pytest.raises(TypeError, match="cull must be a bool"):
        Tracer(cornell, cull="no")
    img = np.random.default_rng(SEED).random((8, 8))
    with pytest.raises(TypeError, match="gaussian_weights must be a bool"):
        M.structural_similarity(img, img, gaussian_weights="no", win_size=3)
    with pytest.raises(TypeError, match="verbose must be a bool"):
        G.grade_values(abs, [1.0], [1.0], verbose="no")


def test_every_registered_boolean_option_is_checked(cornell, no_tracing):
    """Every option whose default is a bool refuses the string 'no' by name."""
    found = 0
    for name, method in METHODS.items():
        for key, default in method.options.items():
            if isinstance(default, bool):
                found += 1
                with pytest.raises(TypeError, match=f"{key} must be a bool"):
                    render(cornell, integrator=name, spp=1, res=2, **{key: "no"})
    assert found >= 3


def test_check_scene_itself_refuses_non_boolean_options(cornell):
    """The registry's contract: ``check_scene`` (run once, in the parent, before
    ``prepare`` and any batch) refuses a bad option; a check left to the batch
    would surface in a worker process."""
    for name, method in METHODS.items():
        for key, default in method.options.items():
            if isinstance(default, bool):
                with pytest.raises(TypeError, match=f"{key} must be a bool"):
                    method.check_scene(cornell, method.resolve_options({key: "no"}))


# --------------------------------------------------------------------------
# 3. Scenes built by hand

def _spoiled(scene, **fields):
    return dataclasses.replace(scene, **fields)


@pytest.mark.parametrize("field, make, error, pattern", [
    ("light_origin", lambda s: np.full_like(s.light_origin, np.nan), ValueError, "light_origin must be finite"),
    ("sphere_centers", lambda s: np.full_like(s.sphere_centers, np.nan), ValueError,
     "sphere_centers must be finite"),
    ("prim_emission", lambda s: np.where(s.prim_emission > 0, np.inf, 0.0), ValueError,
     "prim_emission must be finite"),
    ("prim_emission", lambda s: -np.ones_like(s.prim_emission), ValueError, "prim_emission must be non-negative"),
    ("light_radiance", lambda s: np.full_like(s.light_radiance, np.inf), ValueError,
     "light_radiance must be finite"),
    ("materials", lambda s: ("white",) * len(s.materials), TypeError, r"materials\[0\] must be a mcvar.bsdf"),
    ("materials", lambda s: "white", TypeError, "materials must be a tuple"),
    ("triangles", lambda s: s.triangles[:, :, :2], ValueError, r"triangles must have shape \(n, 3, 3\)"),
    ("triangles", lambda s: s.triangles.reshape(-1, 3), ValueError, r"triangles must have shape \(n, 3, 3\)"),
    ("triangles", lambda s: np.where(np.arange(s.triangles.size).reshape(s.triangles.shape) == 0, 1e300,
                                     s.triangles), ValueError, r"triangles must have coordinates within"),
    ("sphere_radii", lambda s: -s.sphere_radii, ValueError, "sphere_radii must be finite and > 0"),
    ("sphere_radii", lambda s: s.sphere_radii[:1], ValueError, "sphere_radii must have one value per row of sphere_centers"),
    ("light_edge1", lambda s: np.zeros_like(s.light_edge1), ValueError,
     "light_edge1 and light_edge2 must span a parallelogram of positive area"),
    ("light_edge2", lambda s: s.light_edge2 * 1e300, ValueError, "light_edge2 must have coordinates within"),
    ("prim_material", lambda s: s.prim_material + 0.5, ValueError, "prim_material must hold integers"),
    ("prim_light", lambda s: s.prim_light[:3], ValueError, "prim_light must have one row per primitive"),
    ("material_names", lambda s: ("a",), ValueError, "material_names must hold one string per entry of materials"),
    ("camera", lambda s: "camera", TypeError, "camera must be a mcvar.scene.Camera"),
    ("environment", lambda s: 1.0, TypeError, "environment must be None or a mcvar.envmap.EnvironmentMap"),
    ("point_light_position", lambda s: np.full((1, 3), np.nan), ValueError,
     "point_light_position must be finite"),
    ("name", lambda s: 3, TypeError, "Scene.name must be a string"),
])
def test_scene_validates_every_field(field, make, error, pattern):
    scene = load_scene("cornell-spheres")
    with pytest.raises(error, match=pattern):
        _spoiled(scene, **{field: make(scene)})


def test_scene_accepts_what_it_documents():
    """Lists and empty tables of any shape are converted; arrays are read-only."""
    s = load_scene("cornell")
    t = _spoiled(s, triangles=s.triangles.tolist(), sphere_centers=[], sphere_radii=[],
                 point_light_position=None, point_light_intensity=None)
    assert t.triangles.shape == s.triangles.shape and t.sphere_centers.shape == (0, 3)
    np.testing.assert_array_equal(t.triangles, s.triangles)
    assert not t.triangles.flags.writeable and not t.prim_emission.flags.writeable
    big = _spoiled(s, triangles=s.triangles * 1e15)          # within +-1e18: accepted
    assert np.isfinite(big.triangles).all()


# --------------------------------------------------------------------------
# 4. Errors that name their cause

def test_metrics_name_their_arguments():
    a = np.random.default_rng(SEED).random((8, 8, 3))
    with pytest.raises(TypeError, match="eps must be a real number; got str 'a'"):
        M.relative_mse(a, a, eps="a")
    with pytest.raises(ValueError, match="eps must be finite and > 0"):
        M.relative_mse(a, a, eps=-1.0)
    with pytest.raises(TypeError, match="data_range must be a positive finite number; got str 'abc'"):
        M.peak_signal_noise_ratio(a, a + 0.1, data_range="abc")
    with pytest.raises(ValueError, match="channel_axis must be an axis of a colour image.*got 5"):
        M.structural_similarity(a, a, channel_axis=5)
    with pytest.raises(ValueError, match="channel_axis .*a grey image has no channel axis"):
        M.structural_similarity(a[..., 0], a[..., 0], channel_axis=2)
    with pytest.raises(TypeError, match="channel_axis must be None or an int"):
        M.structural_similarity(a, a, channel_axis="last")
    with pytest.raises(TypeError, match="win_size must be None or an odd int"):
        M.structural_similarity(a, a, win_size=3.5)


def test_metric_identities():
    """psnr is 10 log10(range^2 / mse) of the same images; channel_axis -1 and 2
    are one axis; relative_mse against a constant reference c is mse / (c^2 + eps)."""
    rng = np.random.default_rng(SEED)
    ref = rng.random((12, 10, 3))
    est = ref + rng.normal(0, 0.05, ref.shape)
    for dr in (1.0, 2.5):
        assert M.peak_signal_noise_ratio(ref, est, data_range=dr) == pytest.approx(
            10 * math.log10(dr * dr / M.mse(ref, est)), rel=1e-12)
    assert M.structural_similarity(ref, est, channel_axis=-1, data_range=1.0) == \
        M.structural_similarity(ref, est, channel_axis=2, data_range=1.0)
    const = np.full(ref.shape, 0.3)
    assert M.relative_mse(const, est, eps=0.01) == pytest.approx(M.mse(const, est) / (0.09 + 0.01), rel=1e-12)


@pytest.mark.parametrize("returned", [lambda u: np.array(["a"] * len(u)), lambda u: ["x"] * len(u),
                                      lambda u: None, lambda u: [object()] * len(u)])
def test_metropolis_target_returning_non_numbers(returned):
    with pytest.raises(TypeError, match=r"f must return real numbers"):
        mcmc.metropolis(returned, 1, 10, n_bootstrap=100)


def test_sweep_and_chart_name_their_arguments(monkeypatch):
    from mcvar.experiments import measure_chart, sweep
    with pytest.raises(ValueError, match=r"methods \['nosuch'\] are not methods of the integrand 'hemisphere'"):
        sweep("hemisphere", methods=["nosuch"], spp=[4], replicates=3, workers=1, progress=False)
    with pytest.raises(ValueError, match=r"methods \['nosuch:2'\] are not registered integrators"):
        sweep("cornell", methods=["path", "nosuch:2"], spp=[4], replicates=3, workers=1, progress=False, res=4)
    # rng is the Python API's word (issue 20); seed= is its deprecated alias, checked as rng
    with pytest.raises(ValueError, match="rng must be >= 0; got -1"):
        measure_chart(rng=-1, progress=False)
    with pytest.raises(ValueError, match="rng must be >= 0; got -1"), pytest.warns(DeprecationWarning):
        measure_chart(seed=-1, progress=False)
    with pytest.raises(TypeError, match="progress must be a bool"):
        sweep("hemisphere", spp=[4], replicates=3, workers=1, progress="no")


def test_render_names_sampler_dim_and_executor(cornell):
    with pytest.raises(ValueError, match="sampler_dim"):
        render(cornell, spp=1, res=4, sampler="sobol", sampler_dim=HUGE)

    class Bad:
        def submit(self, fn, *args):
            return 1
    with pytest.raises(TypeError, match="executor"):
        render(cornell, spp=4, res=4, batch_spp=1, executor=Bad())


def _cli(capsys, *argv):
    from mcvar.cli import main
    rc = main(list(argv))
    err = capsys.readouterr().err
    return rc, err


def test_cli_one_line_and_status_2(tmp_path, capsys):
    rc, err = _cli(capsys, "converge", "hemisphere", "--methods", "nosuch", "--out", str(tmp_path / "c"), "--quiet")
    assert rc == 2 and err.count("\n") == 1
    assert err.startswith("mcvar converge: error: methods ['nosuch'] are not methods of the integrand")
    out = tmp_path / "image.png"
    out.mkdir()
    # refused before the render starts (the message is the command's own, not the OS's)
    rc, err = _cli(capsys, "render", "cornell", "--spp", "1", "--res", "2", "--uniform", "--quiet",
                   "--out", str(out))
    assert rc == 2 and err.count("\n") == 1 and "is a directory" in err and str(out) in err


def test_cli_lets_genuine_bugs_through(monkeypatch, tmp_path):
    """A KeyError (or any other unanticipated exception) is a bug: traceback, not a one-liner."""
    import mcvar.report as report

    def buggy(*args, **kwargs):
        raise KeyError("a bug")
    monkeypatch.setattr(report, "convergence_report", buggy)
    from mcvar.cli import main
    with pytest.raises(KeyError, match="a bug"):
        main(["converge", "hemisphere", "--out", str(tmp_path / "c"), "--quiet"])


def test_cli_multi_line_messages_become_one_line(monkeypatch, tmp_path, capsys):
    import mcvar.report as report

    def multi(*args, **kwargs):
        raise OSError("disk\nfull")
    monkeypatch.setattr(report, "convergence_report", multi)
    rc, err = _cli(capsys, "converge", "hemisphere", "--out", str(tmp_path / "c"), "--quiet")
    assert rc == 2 and err == "mcvar converge: error: disk full\n"


# --------------------------------------------------------------------------
# 5. Domains that overflow

@pytest.mark.parametrize("lo, hi, pattern", [
    (-1e308, 1e308, "overflows"), (0.0, 1e-320, "overflows"), (1.0, 1.0 + 1e-14, "too narrow for 3 cells"),
    (0.0, float("inf"), "must be finite"), (1.0, 1.0, "min < max"),
])
def test_piecewise_1d_domains_that_overflow(lo, hi, pattern):
    with pytest.raises(ValueError, match=f"domain .*{pattern}"):
        PiecewiseConstant1D([1.0, 2.0, 3.0], lo, hi)


@pytest.mark.parametrize("domain, pattern", [
    (((0.0, 1e308), (-1e308, 0.0)), "domain .*overflows"),
    (((0.0, 1e200), (0.0, 1e200)), "domain .*area"),
    (((0.0, 1e-320), (0.0, 1.0)), r"domain\[0\] .*overflows"),
    (((0.0, 1.0), (5.0, 5.0 + 1e-15)), r"domain\[1\] .*too narrow"),
])
def test_piecewise_2d_domains_that_overflow(domain, pattern):
    with pytest.raises(ValueError, match=pattern):
        PiecewiseConstant2D(np.ones((2, 3)), domain)


@pytest.mark.parametrize("lo, hi", [(0.0, 1.0), (-8e307, 8e307), (1e300, 1.0000001e300), (0.0, 1e-300),
                                    (-3.0, -2.999999)])
def test_piecewise_1d_sample_pdf_invert_identities(lo, hi):
    """pdf(sample(u)) is the returned pdf exactly; invert(sample(u)) = u to the
    rounding of x at the domain's magnitude (relative to the cell width)."""
    rng = np.random.default_rng(SEED)
    d = PiecewiseConstant1D(np.array([1.0, 0.0, 3.0, 0.5, 2.0]), lo, hi)
    u = np.concatenate([rng.random(4000), [0.0, 1.0, np.nextafter(1.0, 0.0)]])
    x, pdf, k = d.sample(u)
    assert np.all(np.isfinite(x)) and np.all((x >= lo) & (x <= hi))
    np.testing.assert_array_equal(d.pdf(x), pdf)
    ulp = np.spacing(max(abs(lo), abs(hi)))
    tol = 4 * ulp / ((hi - lo) / d.size) + 8 * np.finfo(float).eps
    assert np.max(np.abs(d.invert(x) - u)) <= tol
    assert np.isclose(np.sum(d.pmf), 1.0, rtol=1e-15)


def test_piecewise_2d_sample_pdf_identity():
    rng = np.random.default_rng(SEED)
    f = rng.random((7, 5)) * (rng.random((7, 5)) > 0.3)
    d = PiecewiseConstant2D(f, ((-1e150, 1e150), (2.0, 2.5)))
    u = rng.random((3000, 2))
    p, pdf, off = d.sample(u)
    np.testing.assert_array_equal(d.pdf(p), pdf)
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0)


@pytest.mark.parametrize("v", [1e6, 1e300, 1.7e308])
def test_polygon_coverage_at_huge_coordinates(v):
    """A square around the raster covers every pixel exactly once; a unit square
    far away covers nothing; a huge triangle whose edge is y = 0.5 covers half
    of row 0 (coverage stays in [0, 1])."""
    square = np.array([[-v, -v], [v, -v], [v, v], [-v, v]])
    np.testing.assert_array_equal(polygon_pixel_coverage(square, 3, 2), np.ones((2, 3)))
    far = np.array([[v / 2, v / 2], [v / 2 + 1, v / 2], [v / 2 + 1, v / 2 + 1], [v / 2, v / 2 + 1]])
    np.testing.assert_array_equal(polygon_pixel_coverage(far, 3, 2), np.zeros((2, 3)))
    tri = np.array([[-v, 0.5], [v, 0.5], [0.5, v]])
    cov = polygon_pixel_coverage(tri, 3, 2)
    np.testing.assert_allclose(cov, [[0.5] * 3, [1.0] * 3], atol=1e-9)


def test_polygon_coverage_sums_to_the_clipped_area():
    """Identity: the coverages sum to the polygon's area inside the raster (shoelace)."""
    poly = np.array([[0.3, 0.2], [4.7, 1.1], [3.9, 3.6], [0.8, 2.9]])
    cov = polygon_pixel_coverage(poly, 5, 4)
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    assert cov.sum() == pytest.approx(area, rel=1e-12)
    assert cov.min() >= 0.0 and cov.max() <= 1.0


# --------------------------------------------------------------------------
# 6. Graders check their own arguments

def _good_estimator(n, rng):
    return rng.random(n).mean()


def _student_never_called(*args, **kwargs):
    raise _Started("the student's code ran before the grader's arguments were checked")


@pytest.mark.parametrize("call, error, pattern", [
    (lambda: G.grade_estimator(_student_never_called, np.nan, n=10), ValueError, "exact must be finite"),
    (lambda: G.grade_estimator(_student_never_called, [0.5, np.inf], n=10), ValueError, "exact must be finite"),
    (lambda: G.grade_estimator(_student_never_called, "half", n=10), TypeError, "exact must be array-like"),
    (lambda: G.grade_estimator(_student_never_called, 0.5, n=10, significance=1.5), ValueError,
     r"significance must lie in \(0, 1\)"),
    (lambda: G.grade_consistent(_student_never_called, 0.5, [10, 1000], significance=-1), ValueError,
     "significance must be finite and > 0"),
    (lambda: G.grade_consistent(_student_never_called, np.nan, [10, 1000]), ValueError, "exact must be finite"),
    (lambda: G.grade_consistent(_student_never_called, 0.5, [10, 1000], significance=1.5), ValueError,
     r"significance must lie in \(0, 1\)"),
    (lambda: G.grade_consistent(_student_never_called, 0.5, 10), TypeError, "ns must be a sequence"),
    (lambda: G.grade_consistent(_student_never_called, 0.5, [10, 2.5]), ValueError, r"ns\[1\] must be an integer"),
    (lambda: G.grade_bsdf(Lambertian(0.5), wo=[[0.0, 2.0, 0.0]]), ValueError, "wo must hold unit vectors"),
    (lambda: G.grade_bsdf(Lambertian(0.5), wo=np.zeros((0, 3))), ValueError, "wo must hold at least one"),
    (lambda: G.grade_warp(_student_never_called, _student_never_called, "square", significance=0), ValueError,
     "significance must be finite and > 0"),
    (lambda: G.grade_warp(_student_never_called, _student_never_called, "square", rng="abc"), TypeError,
     "rng must be None"),
    (lambda: G.grade_sampler(_student_never_called, 16, randomized="yes"), TypeError,
     "randomized must be a bool"),
    (lambda: G.grade_values(_student_never_called, [1.0], [1.0], rtol=-1.0), ValueError, "rtol must be finite"),
    (lambda: G.grade_estimator(_student_never_called, 0.5, n=10, name=3), TypeError, "name must be a string"),
])
def test_graders_refuse_the_teachers_bad_arguments(call, error, pattern):
    with pytest.raises(error, match=pattern):
        call()


def test_graders_still_grade_good_arguments():
    assert G.grade_estimator(_good_estimator, 0.5, n=64, replicates=16, rng=SEED, verbose=False).passed
    assert G.grade_consistent(_good_estimator, 0.5, [4, 4096], replicates=32, rng=SEED, verbose=False).passed
    wo = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    assert G.grade_bsdf(Lambertian(0.5), wo=wo, n=20_000, rng=SEED, verbose=False).passed


# --------------------------------------------------------------------------
# Found by the deeper fuzz run (MCVAR_FUZZ_EXAMPLES=300), pinned here

def test_found_by_the_fuzzer(cornell, no_tracing):
    # radiosity at patch_size=1: 8 million patches whose side rays cannot fit: patch_size is named
    with pytest.raises(ValueError, match="rays_per_side=256 on the patches of patch_size=1 needs about 182 GiB"):
        render(cornell, integrator="radiosity", spp=1, res=2, patch_size=1)
    # a state of 2**40 path segments was blamed on n_bootstrap=1, an option the user never gave
    with pytest.raises(ValueError, match="state_depth=1099511627776 needs"):
        render(cornell, integrator="pssmlt", spp=1, res=2, state_depth=HUGE)
    with pytest.raises(ValueError, match="dim=1099511627776 needs"):
        mcmc.metropolis(lambda u: u[:, 0], HUGE, 10)
    # a cell of pmf 1e-300 on a domain of width 1e308: its pdf underflowed to 0 and was sampled
    with pytest.raises(ValueError, match="func and domain give a cell whose pdf .* underflows"):
        PiecewiseConstant1D([1.0, 1e300], 0.0, 1e308)
    with pytest.raises(ValueError, match="func and domain give a cell whose pdf"):
        PiecewiseConstant2D([[1e-300, 1.0], [1.0, 1e300]], ((0.0, 1e150), (0.0, 1e150)))


@pytest.mark.parametrize("fn, option", [("sobol", "scramble"), ("halton", "scramble"), ("hammersley", "scramble"),
                                        ("multi_jittered", "correlated")])
def test_sampler_booleans_are_booleans(fn, option):
    from mcvar import samplers
    with pytest.raises(TypeError, match=f"{option} must be a bool"):
        getattr(samplers, fn)(16, **{option: "no"})

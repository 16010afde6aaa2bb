"""PSSMLT (issues 12, 22): agreement with path tracing, consistency, start-up bias, detailed balance of the
lockstep step, the bootstrap's b, workers; cornell-door."""
import math

import numpy as np
import pytest
from scipy import stats

from mcvar.envmap import LUMINANCE_WEIGHTS
from mcvar.integrators import METHODS, render
from mcvar.integrators.pssmlt import (OPTIONS, _Chains, _path_function, _stratified_states, _WeightedRun, pssmlt_film,
                                       state_dim)
from mcvar.scene import load_scene
from mcvar.testing import sidak_significance
from mcvar.tracer import Tracer

import chain_balance  # tests/chain_balance.py
import mcvar.integrators.pssmlt as pssmlt_module


def render_pssmlt(scene, **kw):
    return render(scene, integrator="pssmlt", **kw)

LUM = np.asarray(LUMINANCE_WEIGHTS)
RES = 16
CHAINS = 256          # 16 x 16 pixels: 64 spp = 64 steps per chain


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


@pytest.fixture(scope="module")
def reference(cornell):
    """Path tracing, 1024 spp at 16 x 16 (262 144 paths)."""
    return render(cornell, spp=1024, res=RES, rng=20261201)


@pytest.fixture(scope="module")
def runs64(cornell):
    """Six independent PSSMLT renders of 64 mutations per pixel (and as many bootstrap paths)."""
    seeds = np.random.SeedSequence(64064).spawn(6)
    return [render_pssmlt(cornell, spp=64, res=RES, rng=s, chains=CHAINS, n_bootstrap=64 * RES ** 2)
            for s in seeds]


def test_image_mean_agrees_with_path_tracing(runs64, reference):
    """Per channel, the mean over six independent PSSMLT images agrees with the
    path-traced mean within 5 standard errors (independent runs vs iid pixels)."""
    means = np.array([r.image.mean(axis=(0, 1)) for r in runs64])
    m, se = means.mean(axis=0), means.std(axis=0, ddof=1) / math.sqrt(len(runs64))
    ref = reference.image.mean(axis=(0, 1))
    ref_se = np.sqrt((reference.variance / reference.spp).sum(axis=(0, 1))) / RES ** 2
    assert np.all(np.abs(m - ref) < 5 * np.hypot(se, ref_se)), (m, ref, se, ref_se)
    # the image's mean luminance is the bootstrap's b, up to splats' rounding
    assert all(r.image.mean(axis=(0, 1)) @ LUM > 0 for r in runs64)


def test_mse_falls_with_spp(cornell, reference, runs64):
    """Consistency: log MSE against the reference at 2 vs 64 mutations per pixel,
    12 and 6 independent runs, one-sided Welch t-test p < 1e-3 (log: MSE is heavy-tailed).
    The bootstrap grows with the mutations (n_bootstrap = mutations) so that its
    error in b, a global scale, falls at the same rate."""
    seeds = np.random.SeedSequence(404).spawn(12)
    low = [np.mean((render_pssmlt(cornell, spp=2, res=RES, rng=s, chains=CHAINS,
                                  n_bootstrap=2 * RES ** 2).image - reference.image) ** 2)
           for s in seeds]
    high = [np.mean((r.image - reference.image) ** 2) for r in runs64]
    assert stats.ttest_ind(np.log(low), np.log(high), equal_var=False, alternative="greater").pvalue < 1e-3, \
        (low, high)


def test_bootstrap_removes_start_up_bias(cornell, reference):
    """One mutation per chain (spp = 1, one chain per pixel): the image is the
    chains' starting distribution. Started from the bootstrap's resampled paths,
    the share of luminance in the reference's darker half of pixels agrees with
    the reference (5 SE over 6 runs); started from uniformly drawn lit paths, it
    is far too large (start-up bias)."""
    lum = reference.image @ LUM
    dark = lum < np.median(lum)
    truth = lum[dark].sum() / lum.sum()
    share = {}
    for boot in (True, False):
        vals = []
        for s in np.random.SeedSequence(1717).spawn(6):
            img = render_pssmlt(cornell, spp=1, res=RES, rng=s, chains=RES * RES, bootstrap=boot).image @ LUM
            vals.append(img[dark].sum() / img.sum())
        share[boot] = (np.mean(vals), np.std(vals, ddof=1) / math.sqrt(6))
    (m_b, se_b), (m_u, se_u) = share[True], share[False]
    assert abs(m_b - truth) < 5 * se_b + 0.01, (share, truth)   # + the reference's own share noise
    assert m_u - truth > 5 * se_u and m_u > 2 * truth, (share, truth)


def test_pssmlt_bookkeeping_and_bad_input(cornell):
    run = pssmlt_film(cornell, (4, 4), 2, rng=3, chains=8)
    assert run.spp == 8 * 4 / 16 and run.sum.shape == (16, 3) and 0 < run.acceptance_rate <= 1
    assert run.rays > 0 and run.b > 0 and run.b_stderr > 0
    assert METHODS["pssmlt"].kind == "chain" and dict(METHODS["pssmlt"].options) == OPTIONS
    assert state_dim(6) == 2 + 6 * 5 and state_dim(6, max_depth=2) == 8 and state_dim(1) == 2
    # two independent batches: the film's variance from their spread
    r = render_pssmlt(cornell, spp=8, res=4, rng=5, batch_spp=4, chains=16)
    assert r.spp == 8 and r.variance is not None and np.all(np.isfinite(r.variance))
    with pytest.raises(ValueError, match="sigma"):
        pssmlt_film(cornell, (4, 4), 1, sigma=0.0)
    with pytest.raises(ValueError, match="p_large"):
        pssmlt_film(cornell, (4, 4), 1, p_large=2.0)
    with pytest.raises(ValueError, match="spp"):
        pssmlt_film(cornell, (4, 4), float("nan"))
    with pytest.raises(ValueError, match="option"):
        render_pssmlt(cornell, spp=1, res=4, colour="red")
    with pytest.raises(ValueError, match="sigma"):
        render_pssmlt(cornell, spp=1, res=4, sigma=-1.0)
    with pytest.raises(ValueError, match="carries light"):
        pssmlt_film(load_scene("cornell-door", slit=1e-6), (2, 2), 1, n_bootstrap=4, chains=2, rng=0)


def test_a_path_is_a_pure_function_of_the_state(cornell):
    """With max_depth <= state_depth the chain's target is deterministic in u
    (the primary sample space); beyond the cap the tail is fresh (documented)."""
    u = np.random.default_rng(9).random((512, state_dim(6, 4)))
    a = _path_function(cornell, (8, 8), Tracer(cornell), 4, "power", np.random.default_rng(1), [0])(u)
    b = _path_function(cornell, (8, 8), Tracer(cornell), 4, "power", np.random.default_rng(2), [0])(u)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert np.count_nonzero(a[0]) > 100


def test_cornell_door_geometry_and_light_only_through_the_slit():
    door = load_scene("cornell-door")
    assert door.name == "cornell-door" and door.n_triangles == 32 - 10 + 6     # no tall block, 3 wall quads
    assert door.light_origin[0, 2] > 400.0                                      # the light is behind the wall
    with pytest.raises(ValueError, match="slit"):
        load_scene("cornell-door", slit=600.0)
    with pytest.raises(ValueError, match="wall_z"):
        load_scene("cornell-door", wall_z=500.0)
    with pytest.raises(ValueError, match="height"):
        load_scene("cornell-door", height=600.0)
    assert load_scene("cornell-door", height=548.8).n_triangles == 32 - 10 + 4  # full height: no lintel
    # narrowing the slit darkens the visible room: direct light (depth 2) through a
    # 20-unit slit vs a 2-unit one (8 x 8 pixels, 256 spp): brighter by > 5 SE
    wide = render(door, integrator="direct", spp=256, res=8, rng=1)
    narrow = render(load_scene("cornell-door", slit=2.0), integrator="direct", spp=256, res=8, rng=1)
    w, n = wide.image.mean(), narrow.image.mean()
    se = math.hypot(*(np.sqrt((r.variance / r.spp).sum()) / r.image.size for r in (wide, narrow)))
    assert w - n > 5 * se, (w, n, se)


def test_cornell_door_behind_the_block_hides_the_closet_and_every_directly_lit_surface():
    """The door configuration of docs/mcmc.md's 'door behind the block' (slit 5 wide, 120 high at
    x = 200): no primary ray passes the partition (the short block hides the slit), and no point the
    camera sees is lit directly (direct lighting is exactly 0), while the room is lit (indirectly)."""
    kw = dict(slit=5.0, center=200.0, height=120.0)
    scene = load_scene("cornell-door", **kw)
    res = (64, 64)
    n = res[0] * res[1]
    d = scene.camera.ray_directions(res, np.arange(n), np.random.default_rng(0).random((n, 2)))
    o = np.broadcast_to(scene.camera.position, (n, 3))
    hit = Tracer(scene).intersect(o, d)
    z = o[:, 2] + d[:, 2] * np.where(hit.hit, hit.t, 0.0)
    assert hit.hit.mean() > 0.5 and np.all(z < 400.5)  # float32 hits; misses: outside the open room
    direct = render(scene, integrator="direct", spp=64, res=16, rng=1)
    assert np.count_nonzero(direct.image) == 0
    lit = render(scene, integrator="path", spp=4096, res=4, rng=1, max_depth=5)
    assert lit.image.mean() > 5 * np.sqrt((lit.variance / lit.spp).sum()) / lit.image.size
    # the default door is seen through: some primary rays reach the closet
    hit = Tracer(load_scene("cornell-door")).intersect(o, d)
    assert np.count_nonzero(o[:, 2] + d[:, 2] * np.where(hit.hit, hit.t, 0.0) > 400.5) > 0


# -- the lockstep step, the bootstrap's b, workers (issue 22) ------------------------------------

ALPHA = 1e-3


def _analytic_target(yT):
    """``_Chains``' target protocol on the analytic density of tests/chain_balance.py."""
    f = chain_balance.target(yT.T)
    return f, np.zeros(f.shape[0], dtype=np.intp), np.zeros((3, f.shape[0]))


@pytest.mark.parametrize("sigma,p_large", [(0.1, 0.3), (0.02, 0.0)])
def test_lockstep_step_keeps_detailed_balance_and_the_target(sigma, p_large):
    """One step of 200 000 chains started exactly on f = 4 u0 u1 (pssmlt's own mutation,
    acceptance and move): the transitions between 16 cells are symmetric (Bowker) and the
    states after the step are still distributed as f (chi-square); Sidak over the 4 tests."""
    rng = np.random.default_rng(20261202)
    x = chain_balance.exact_samples(200_000, rng)
    chains = _Chains(np.ascontiguousarray(x.T), chain_balance.target(x), np.zeros(len(x), dtype=np.intp),
                     np.zeros((3, len(x))))
    before = chains.xT.T.copy()
    prop = chains.propose(_analytic_target, sigma, p_large, rng)
    chains.move(prop)
    after = chains.xT.T
    assert 0.05 < prop.accept.mean() < 1.0                       # the step moves chains
    alpha = sidak_significance(ALPHA, 4)
    assert chain_balance.bowker_pvalue(before, after) > alpha
    assert chain_balance.stationarity_pvalue(after) > alpha


def test_image_mean_luminance_is_b_and_b_agrees_with_path_tracing(cornell):
    """Identity: every step splats luminance 1 in all (1 - a + a), so the image's mean
    luminance is b exactly (both splats). And b, the mean of f over the run's iid uniform
    states, agrees with path tracing's image mean luminance within 5 standard errors
    (8 independent path renders for its error)."""
    for splat in ("expected", "plain"):
        run = pssmlt_film(cornell, (8, 8), 32, rng=5150, chains=512, splat=splat)
        image = run.sum / run.spp
        assert (image @ LUM).mean() == pytest.approx(run.b, rel=1e-12)
        assert run.n_b > run.n_bootstrap > 0 and run.b_stderr > 0
    lum = [render(cornell, spp=64, res=8, rng=s).image @ LUM for s in np.random.SeedSequence(77).spawn(8)]
    means = np.array([m.mean() for m in lum])
    se_path = means.std(ddof=1) / math.sqrt(len(means))
    assert abs(run.b - means.mean()) < 5 * math.hypot(run.b_stderr, se_path), (run.b, run.b_stderr, means)


def test_workers_and_seed_give_the_same_image(cornell):
    """The image is a pure function of the seed: two workers (processes), one worker and a
    second run with the same seed give identical images and diagnostics."""
    kw = dict(integrator="pssmlt", spp=8, res=8, batch_spp=2, chains=64, rng=31337)
    one, two, again = render(cornell, **kw), render(cornell, workers=2, **kw), render(cornell, **kw)
    np.testing.assert_array_equal(one.image, two.image)
    np.testing.assert_array_equal(one.image, again.image)
    for key in one.extra:
        np.testing.assert_array_equal(one.extra[key], two.extra[key])


def test_diagnostics_of_a_run(cornell):
    """The film's diagnostics: acceptance in (0, 1), 1 <= tau <= n_steps (up to the
    estimate's noise) and ESS = N / tau; the render reports them per batch."""
    run = pssmlt_film(cornell, (8, 8), 64, rng=99, chains=256)
    assert run.chains == 256 and run.n_steps == 16 and 0 < run.acceptance_rate < 1
    for name in ("luminance", "film_x", "film_y"):
        assert 0.5 < run.tau[name] < 2 * run.n_steps
        assert run.ess[name] == pytest.approx(run.chains * run.n_steps / run.tau[name])
    r = render_pssmlt(cornell, spp=8, res=8, rng=3, chains=64)
    assert {"b", "b_stderr", "acceptance_rate", "tau", "ess_fraction"} <= set(r.extra)


# -- start='weighted': every lit bootstrap path starts a chain weighted by its f (issue 22) --------

def _cell_target(yT):
    """The analytic target with the cell of the state as its 'pixel' and colour ``c = f``
    (``rgb / f = (1, 0, 0)``): a weighted run's film estimates ``n_cells * ∫_cell f``."""
    u = yT.T
    f = chain_balance.target(u)
    rgbn = np.zeros((3, f.shape[0]))
    rgbn[0] = 1.0
    return f, chain_balance.cell(u), rgbn


def _weighted_cells(n_b, n_steps, sigma, p_large, rng, round_size=1000):
    n_cells = chain_balance.CELLS ** 2
    run = _WeightedRun(n_cells, n_steps, _cell_target, (sigma, p_large), rng)
    a = 0
    while a < n_b:
        m = run.births_allowed(min(round_size, n_b - a))
        run.bootstrap_chunk(rng.random((chain_balance.DIM, m)))
        a += m
    run.finish()
    assert run.done == n_b and run.n_chains == n_b      # f > 0 almost everywhere: every start is a chain
    return run.image_sum(n_cells)[:, 0] / (n_b / n_cells), run


@pytest.mark.parametrize("n_steps,sigma,p_large,cap", [(8, 0.1, 0.0, None), (3, 0.02, 0.3, 1500)])
def test_weighted_chains_estimate_the_cells_mass_without_bias(n_steps, sigma, p_large, cap, monkeypatch):
    """Veach's weighted start on f = 4 u0 u1: chains started at uniform states with weight
    f(x0), T steps of pssmlt's own mutation and acceptance, expected-value splats, the chains'
    steps traced in the rounds of new states (and, with ``cap``, rounds that wait for chains
    to retire); the film of each of 36 cells against its exact mass n_cells (b^2 - a^2)(d^2 - c^2):
    20 independent runs, Student t per cell, Sidak over the 36 cells x 2 cases."""
    if cap is not None:
        monkeypatch.setattr(pssmlt_module, "MAX_CHAINS_IN_FLIGHT", cap)
    rng = np.random.default_rng(2026_12_02 + n_steps)
    n_cells = chain_balance.CELLS ** 2
    est = np.array([_weighted_cells(4000, n_steps, sigma, p_large, rng)[0] for _ in range(20)])
    truth = n_cells * chain_balance.cell_masses()
    se = est.std(axis=0, ddof=1) / math.sqrt(len(est))
    t = (est.mean(axis=0) - truth) / se
    p = 2 * stats.t.sf(np.abs(t), df=len(est) - 1)
    assert p.min() > sidak_significance(ALPHA, 2 * n_cells), (t, p.min())


def test_weighted_run_identities(cornell):
    """chain_length=0 is path tracing over the stratified bootstrap (the image's mean luminance is
    b, the mean of f over it); with chains every step deposits luminance f(x0) in all, so the
    identity holds for any chain length; spp is the bootstrap's paths per pixel."""
    for n_steps in (0, 5):
        run = pssmlt_film(cornell, (8, 8), 4, rng=11, start="weighted", chain_length=n_steps)
        image = run.sum / run.spp
        assert run.spp == 4 and run.n_bootstrap == run.n_b == 4 * 64 and run.n_steps == n_steps
        assert (image @ LUM).mean() == pytest.approx(run.b, rel=1e-12)
        assert 0 < run.chains <= run.n_bootstrap
    assert 0 < run.acceptance_rate < 1 and run.b_stderr > 0
    for name in ("luminance", "film_x", "film_y"):
        assert 0.5 < run.tau[name] < 2 * (n_steps + 1)
    # the bootstrap is stratified: every pixel has exactly spp starts, in scanline passes
    states = _stratified_states((8, 8), 0, 8 * 8 * 3, 4, np.random.default_rng(0))
    col = np.floor(states[0] * 8).astype(int)
    row = np.floor(states[1] * 8).astype(int)
    np.testing.assert_array_equal(np.bincount(row * 8 + col, minlength=64), 3)
    np.testing.assert_array_equal(row * 8 + col, np.arange(64 * 3) % 64)


def test_weighted_image_agrees_with_path_tracing_per_block():
    """cornell-door at 8 x 8, 2 x 2 blocks x 3 channels: the mean of 8 independent weighted
    renders (32 chain steps from every lit bootstrap path) against path tracing at 4 096 spp,
    5 combined standard errors, Sidak over the 48 block means at alpha = 1e-3 (the z of 5 is the
    looser of the two)."""
    door = load_scene("cornell-door")
    ref = render(door, spp=4096, res=8, rng=909)
    runs = [render_pssmlt(door, spp=256, res=8, rng=s, start="weighted", chain_length=32, p_large=0.0,
                          batch_spp=256).image for s in np.random.SeedSequence(808).spawn(8)]
    blocks = lambda img: img.reshape(4, 2, 4, 2, 3).mean(axis=(1, 3)).reshape(-1)   # noqa: E731
    est = np.array([blocks(im) for im in runs])
    m, se = est.mean(axis=0), est.std(axis=0, ddof=1) / math.sqrt(len(est))
    ref_se = np.sqrt(blocks(ref.variance / ref.spp) / 4)       # a block's mean of 4 independent pixels
    z = (m - blocks(ref.image)) / np.hypot(se, ref_se)
    limit = max(5.0, stats.norm.isf(sidak_significance(ALPHA, z.size) / 2))
    assert np.all(np.abs(z) < limit), z


def test_weighted_options_refused_before_work(cornell):
    with pytest.raises(ValueError, match="start"):
        render_pssmlt(cornell, spp=1, res=4, start="uniform")
    with pytest.raises(ValueError, match="chain_length"):
        render_pssmlt(cornell, spp=1, res=4, start="weighted", chain_length=-1)
    with pytest.raises(TypeError, match="chain_length"):
        render_pssmlt(cornell, spp=1, res=4, start="weighted", chain_length=2.5)
    with pytest.raises(ValueError, match="n_bootstrap"):
        render_pssmlt(cornell, spp=1, res=4, start="weighted", n_bootstrap=64)
    with pytest.raises(ValueError, match="bootstrap=False"):
        pssmlt_film(cornell, (4, 4), 1, start="weighted", bootstrap=False)


def test_weighted_workers_and_seed_give_the_same_image(cornell):
    kw = dict(integrator="pssmlt", spp=8, res=8, batch_spp=2, start="weighted", chain_length=4, rng=4242)
    one, two, again = render(cornell, **kw), render(cornell, workers=2, **kw), render(cornell, **kw)
    np.testing.assert_array_equal(one.image, two.image)
    np.testing.assert_array_equal(one.image, again.image)


@pytest.mark.parametrize("recipe,depth", [("cornell", None), ("cornell", 3), ("cornell-door", 2)])
def test_weighted_agrees_with_mitsuba(recipe, depth):
    """start='weighted' against the stored Mitsuba 3 references (tests/test_mitsuba_reference.py's
    block t-tests, Sidak, and its skewness guard): 8 independent renders of 64 bootstrap paths per
    pixel, one run each. cornell-door at full depth is heavy-tailed for every camera method
    (documented there), so the door is compared at max_depth 2 like mmlt."""
    import test_mitsuba_reference as mitsuba
    images = mitsuba.mcvar_replicates(recipe, "pssmlt", 64, 8, max_depth=depth, start="weighted", batch_spp=64)
    mitsuba.assert_agrees(images, mitsuba._case_name(recipe, depth),
                          f"pssmlt start='weighted' max_depth={depth} (8 x 64 spp) on {recipe}",
                          mitsuba.region_of(recipe))


def test_weighted_run_interrupted_keeps_the_finished_rounds():
    """Ctrl-C in the 6th round (the target raises) keeps the 5 finished rounds: interrupted, spp is
    their share of the bootstrap, the film is finite; Ctrl-C in the first round is re-raised."""
    from mcvar.integrators.pssmlt import PssmltSettings, _weighted_film

    class Stop:
        def __init__(self, after):
            self.calls, self.after, self.rays = 0, after, 0

        def __call__(self, yT):
            self.calls += 1
            if self.calls > self.after:
                raise KeyboardInterrupt
            return _cell_target(yT)

    opts = PssmltSettings(start="weighted", chain_length=3, p_large=0.0)
    old = pssmlt_module.WEIGHTED_ROUND
    try:
        pssmlt_module.WEIGHTED_ROUND = 360                     # 10 scanline passes of 6 x 6 per round
        run = _weighted_film(Stop(5), chain_balance.DIM, (6, 6), 100, opts, np.random.default_rng(1))
        assert run.interrupted and 0 < run.spp < 100 and np.all(np.isfinite(run.sum))
        # D: each of the 5 rounds' 360 new states (t = 0), plus the states of the cohorts born in
        # the 3 rounds before (0, 1, 2, 3, 3 cohorts): 1800 + 3240 terms, spp = D / ((T + 1) n_pix)
        assert run.spp == (5 * 360 + 360 * (0 + 1 + 2 + 3 + 3)) / (4 * 36)
        with pytest.raises(KeyboardInterrupt):
            _weighted_film(Stop(0), chain_balance.DIM, (6, 6), 100, opts, np.random.default_rng(1))
    finally:
        pssmlt_module.WEIGHTED_ROUND = old


def test_weighted_run_without_light_is_black():
    """A closed door: no bootstrap path carries light. Resampling cannot start (ValueError); the
    weighted estimate is path tracing's, zero, with NaN chain diagnostics (no chain ran)."""
    dark = load_scene("cornell-door", slit=1e-6)
    r = render_pssmlt(dark, spp=2, res=4, rng=0, start="weighted")
    assert r.spp == 2 and np.count_nonzero(r.image) == 0 and np.isnan(r.extra["tau"]).all()
    run = pssmlt_film(dark, (4, 4), 2, rng=0, start="weighted")
    assert run.chains == 0 and run.b == 0.0 and run.acceptance_rate == 0.0


def test_interrupted_weighted_render_is_unbiased():
    """Cut every weighted run after 3 of its 8 rounds (a run of 2 scanline passes per round,
    chain_length 8: the cohorts have made 3, 2 and 1 steps): the image still agrees with path
    tracing per 2 x 2 block and channel (cornell, 8 x 8, 12 runs, 5 combined SE / Sidak). With
    rounds that each covered a part of the image instead (pixel-major order) the top rows would
    carry all of it (tried: the cut render of the first design had 5x the MSE)."""
    from mcvar.integrators.pssmlt import PssmltSettings, _PathTarget, _weighted_film
    from mcvar.integrators.settings import PathSettings
    cornell = load_scene("cornell")
    ref = render(cornell, spp=2048, res=8, rng=77)
    old = pssmlt_module.WEIGHTED_ROUND
    images = []
    try:
        pssmlt_module.WEIGHTED_ROUND = 128                      # 2 passes of 8 x 8 per round
        for seed in np.random.SeedSequence(1234).spawn(12):
            rng = np.random.default_rng(seed)
            target = _PathTarget(cornell, (8, 8), Tracer(cornell), PathSettings(), rng)
            calls = [0]

            def cut(yT, target=target, calls=calls):
                calls[0] += 1
                if calls[0] > 3:
                    raise KeyboardInterrupt
                return target(yT)
            cut.rays = 0
            run = _weighted_film(cut, state_dim(6), (8, 8), 16, PssmltSettings(start="weighted", chain_length=8,
                                                                                 p_large=0.0), rng)
            assert run.interrupted and run.spp == (3 * 128 + 128 * (0 + 1 + 2)) / (9 * 64)
            images.append((run.sum / run.spp).reshape(8, 8, 3))
    finally:
        pssmlt_module.WEIGHTED_ROUND = old
    blocks = lambda img: img.reshape(4, 2, 4, 2, 3).mean(axis=(1, 3)).reshape(-1)   # noqa: E731
    est = np.array([blocks(im) for im in images])
    m, se = est.mean(axis=0), est.std(axis=0, ddof=1) / math.sqrt(len(est))
    ref_se = np.sqrt(blocks(ref.variance / ref.spp) / 4)
    z = (m - blocks(ref.image)) / np.hypot(se, ref_se)
    limit = max(5.0, stats.norm.isf(sidak_significance(ALPHA, z.size) / 2))
    assert np.all(np.abs(z) < limit), z

"""MMLT (issue 22): unbiased against BDPT, the bootstrap's b, detailed balance, workers, bad input."""
import numpy as np
import pytest
from scipy import stats

from mcvar.integrators import render
from mcvar.integrators.bdpt import BDPTSettings, bdpt_contributions
from mcvar.integrators.emitters import LightOrigins
from mcvar.integrators.light import _Context
from mcvar.integrators.mmlt_lambertian import Workspace
from mcvar.integrators.mmlt import MmltSettings, StateLayout, lockstep, mmlt_film, stratified_states
from mcvar.integrators.mmlt import _direct_image, _morton, _systematic
from mcvar.integrators.mmlt_states import bootstrap_splats, bootstrap_values, evaluate_states, strategy_columns
from mcvar.scene import load_scene
from mcvar.tracer import Tracer

LUM = np.array([0.2126, 0.7152, 0.0722])
#: 5 standard errors two-sided for the family, Sidak-corrected per check
FAMILY = 2 * stats.norm.sf(5.0)


def _z(k):
    return stats.norm.isf((1.0 - (1.0 - FAMILY) ** (1.0 / k)) / 2)


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


def test_state_layout_holds_three_streams():
    lay = StateLayout(5)
    # camera: film 2 + 2 per scattering vertex (4); light: origin 4 + 2 per scattering vertex (3); strategy 1
    assert (lay.camera_vertices, lay.light_origin, lay.light_vertices, lay.strategy, lay.dim) == \
        (slice(2, 10), slice(10, 14), slice(14, 20), 20, 21)


def test_stratified_bootstrap_states_fill_every_pixel_and_each_pairs_cells():
    """4 states per pixel (8 x 8): every pixel 4 times, and in each pixel every column pair (the
    film position inside the pixel, each vertex's 2D sample) takes the 4 cells of a 2 x 2 grid, the
    odd last column its 4 strata; over many draws each state's numbers are uniform (chi-square)."""
    x = stratified_states(256, 7, (8, 8), np.random.default_rng(1))
    pix = (x[:, 1] * 8).astype(int) * 8 + (x[:, 0] * 8).astype(int)
    assert sorted(pix) == sorted(list(range(64)) * 4)
    inner = np.stack([x[:, 0] * 8 % 1, x[:, 1] * 8 % 1, *x[:, 2:].T], axis=1)     # film: within the pixel
    for p in range(64):
        u = inner[pix == p]
        for c in (0, 2, 4):
            cells = (u[:, c] * 2).astype(int) + 2 * (u[:, c + 1] * 2).astype(int)
            assert sorted(cells) == [0, 1, 2, 3]
        assert sorted((u[:, 6] * 4).astype(int)) == [0, 1, 2, 3]
    # marginal uniformity: state 0's numbers over independent draws
    draws = np.array([stratified_states(256, 7, (8, 8), np.random.default_rng(100 + k))[0] for k in range(400)])
    for c in range(7):
        assert stats.kstest(draws[:, c], "uniform").pvalue > 1e-3


def test_systematic_resampling_draws_each_candidate_in_proportion_to_its_weight():
    """The chains' starts (:func:`_systematic`): over R independent offsets, candidate ``i``'s mean count
    equals ``c w_i / sum(w)`` within 5 sigma (Sidak over the candidates; the count's variance is
    at most ``e (1 - e)`` for ``e`` the fractional part of its expectation, a count being ``floor`` or
    ``ceil`` of it, and otherwise derived from the runs' spread), and in *every* run any contiguous
    stretch of the order holds ``c q`` draws to within one (``q`` its share of the weight): the
    property independent draws lack (their spread is ``sqrt(c q (1 - q))``)."""
    rng = np.random.default_rng(7)
    rows, k, c, R = 300, 3, 257, 4000
    w = rng.gamma(0.3, size=rows * k) * (rng.random(rows * k) < 0.5)      # sparse, skewed: many zeros
    order = rng.permutation(rows)
    counts = np.zeros((R, w.size))
    for r in range(R):
        cand = _systematic(w, c, order, k, np.random.default_rng(1000 + r))
        counts[r] = np.bincount(cand, minlength=w.size)
    expect = c * w / w.sum()
    assert np.all(counts[:, w == 0] == 0)
    frac = expect - np.floor(expect)
    var = np.maximum(counts.var(axis=0, ddof=1), frac * (1 - frac))
    z = (counts.mean(axis=0) - expect)[w > 0] / np.sqrt(var[w > 0] / R + 1e-300)
    assert np.all(np.abs(z) < _z(z.size)), np.abs(z).max()
    # contiguous stretches of the order: every run, every stretch, within one draw
    idx = (order[:, None] * k + np.arange(k)).ravel()
    cum_w = np.concatenate([[0.0], np.cumsum(w[idx])]) * (c / w.sum())
    cum_n = np.concatenate([np.zeros((R, 1)), np.cumsum(counts[:, idx], axis=1)], axis=1)
    a, b = rng.integers(0, idx.size + 1, size=(2, 500))
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    dev = (cum_n[:, hi] - cum_n[:, lo]) - (cum_w[hi] - cum_w[lo])
    assert np.abs(dev).max() <= 1.0 + 1e-9


def test_morton_codes_keep_nearby_pixels_nearby():
    """:func:`_morton`: distinct codes for distinct pixels, and each aligned 2^j x 2^j block of pixels a
    contiguous run of codes (the Z order the starts are resampled along)."""
    res = (16, 8)
    ix, iy = np.meshgrid(np.arange(16), np.arange(8), indexing="ij")
    film = np.stack([(ix.ravel() + 0.5) / 16, (iy.ravel() + 0.5) / 8], axis=1)
    code = _morton(film, res)
    assert np.unique(code).size == 128
    for j in (1, 2, 3):
        block = (ix.ravel() >> j) * 100 + (iy.ravel() >> j)
        for blk in np.unique(block):
            cb = np.sort(code[block == blk])
            assert cb[-1] - cb[0] == cb.size - 1


def test_mmlt_is_unbiased_against_bdpt_per_block(cornell):
    """Block means (4 blocks of 4 x 4 pixels x 3 channels) of R independent MMLT runs against R
    independent BDPT renders at the same depth: |z| below 5 sigma, Sidak over the 12 checks (the
    variance of each side from its runs' spread)."""
    res, depth, R = 8, 3, 12
    seeds = np.random.SeedSequence(2201).spawn(2 * R)

    def blocks(img):
        return img.reshape(2, 4, 2, 4, 3).mean(axis=(1, 3)).reshape(4, 3)

    m = np.array([blocks(render(cornell, method="mmlt", spp=64, res=res, rng=s, max_depth=depth, batch_spp=64,
                                chains=512).image) for s in seeds[:R]])
    b = np.array([blocks(render(cornell, method="bdpt", spp=32, res=res, rng=s, max_depth=depth).image)
                  for s in seeds[R:]])
    se = np.sqrt(m.var(axis=0, ddof=1) / R + b.var(axis=0, ddof=1) / R)
    z = (m.mean(axis=0) - b.mean(axis=0)) / se
    assert np.all(np.abs(z) < _z(z.size)), (z, _z(z.size))


def test_bootstrap_b_per_depth_is_the_image_integral_of_that_depth(cornell):
    """b_d (the bootstrap's mean of (d + 1) Y(w C) over uniform states) against the mean luminance of
    BDPT's depth-d strategy images (sum over s + t - 1 = d): the same integral two ways, within
    5 sigma Sidak over the depths (BDPT's error from 8 independent runs)."""
    res, depth = 8, 3
    run = mmlt_film(cornell, (res, res), 16, rng=7, max_depth=depth, chains=256, n_bootstrap=8192)
    tr = Tracer(cornell)
    n_pix = res * res
    per_depth = []
    for seed in range(8):
        pixel = np.repeat(np.arange(n_pix), 64)
        rng = np.random.default_rng(100 + seed)
        out = bdpt_contributions(cornell, tr, LightOrigins(cornell), (res, res), pixel, rng.random((pixel.size, 2)),
                                 rng, BDPTSettings(max_depth=depth, strategies=True))
        per = out[4]
        per_depth.append([sum((per[k] / 64) @ LUM for k in per if sum(k) - 1 == d).mean()
                          for d in range(1, depth + 1)])
    per_depth = np.array(per_depth)
    truth, t_se = per_depth.mean(axis=0), per_depth.std(axis=0, ddof=1) / np.sqrt(8)
    z = (run.b - truth) / np.sqrt(run.b_stderr ** 2 + t_se ** 2)
    assert np.all(np.abs(z) < _z(depth)), (run.b, truth, z)
    # and the image's mean luminance is sum_d b_d exactly (a Y(c) / f = 1 identity of the splats)
    img = run.sum / run.spp
    assert (img @ LUM).mean() == pytest.approx(run.b.sum(), rel=1e-9)


def _target(u):
    """f(u) = (u0 + 0.1) (1 on u1 < 1/2, 1/4 above), 0 on a band u0 in [0.4, 0.5): a gap the small
    steps must cross."""
    f = (u[:, 0] + 0.1) * np.where(u[:, 1] < 0.5, 1.0, 0.25)
    return np.where((u[:, 0] >= 0.4) & (u[:, 0] < 0.5), 0.0, f)


def _bin_probabilities(k):
    """P(bin) of f / b on a k x k grid, exactly (f is linear in u0 and piecewise constant in u1)."""
    e = np.linspace(0, 1, k + 1)
    px = np.array([((b + 0.1) ** 2 - (a + 0.1) ** 2) / 2 for a, b in zip(e[:-1], e[1:])])
    a0, a1 = e[:-1], e[1:]
    gap_lo, gap_hi = np.maximum(a0, 0.4), np.minimum(a1, 0.5)
    gap = np.where(gap_hi > gap_lo, ((gap_hi + 0.1) ** 2 - (gap_lo + 0.1) ** 2) / 2, 0.0)
    px = px - gap
    py = np.array([(min(b, 0.5) - min(a, 0.5)) * 1.0 + (max(b, 0.5) - max(a, 0.5)) * 0.25
                   for a, b in zip(e[:-1], e[1:])])
    p = np.outer(px, py)
    return p / p.sum()


@pytest.mark.parametrize("sigma,p_large", [(0.05, 0.0), (0.05, 0.3), (0.3, 0.1)])
def test_lockstep_mutation_keeps_its_target_invariant(sigma, p_large):
    """Detailed balance, checked as invariance: chains started *exactly* from f / b (rejection
    sampling) are still distributed as f / b after 8 lockstep steps; their final states are iid
    across chains, so a chi-square test of their 8 x 8 histogram against the exact bin
    probabilities is exact (p > 1e-4, three settings)."""
    rng = np.random.default_rng(int(sigma * 1000) + int(p_large * 10))
    n, k = 40_000, 8
    cand = rng.random((4 * n, 2))
    keep = rng.random(4 * n) * 1.1 < _target(cand)
    x = cand[keep][:n]
    assert x.shape[0] == n

    def evaluate(y):
        return _target(y), (np.zeros(y.shape[0]),)

    x, fx, values, acc = lockstep(evaluate, (x, _target(x), (np.zeros(n),)), 8, (sigma, p_large), rng)
    assert values.shape == (8, n) and 0 < acc.sum() < 8 * n
    assert np.all(_target(x) > 0) and np.array_equal(fx, _target(x))
    hist = np.histogram2d(x[:, 0], x[:, 1], bins=k, range=[[0, 1], [0, 1]])[0]
    p = _bin_probabilities(k)
    ok = p.ravel() > 0
    assert np.all(hist.ravel()[~ok] == 0)                                 # never in the gap
    chi2 = stats.chisquare(hist.ravel()[ok], n * p.ravel()[ok])
    assert chi2.pvalue > 1e-4, chi2


def test_workers_two_give_the_image_of_one():
    scene = load_scene("cornell-door")
    kw = dict(method="mmlt", spp=4, res=8, rng=2205, batch_spp=2, max_depth=4, chains=64, n_bootstrap=4096)
    a = render(scene, workers=1, **kw)
    b = render(scene, workers=2, **kw)
    np.testing.assert_array_equal(a.image, b.image)
    assert b.spp == 4 and "b_depth" in b.extra and b.extra["b_depth"].shape == (4,)


def test_diagnostics_per_depth():
    scene = load_scene("cornell")
    run = mmlt_film(scene, (8, 8), 64, rng=3, max_depth=3, chains=128)
    assert run.n_steps == 32 and run.chains.sum() == 128
    assert run.b.shape == run.b_stderr.shape == run.tau.shape == run.ess.shape == (3,)
    assert np.all(run.b_stderr > 0) and 0 < run.acceptance_rate < 1
    lit = run.chains > 0
    assert np.all(run.tau[lit] >= 1) and np.allclose(run.ess[lit], run.chains[lit] * 32 / run.tau[lit])
    # the mean acceptance probabilities of large and small steps: in [0, 1] where chains run; given the
    # probabilities the accept draws are independent Bernoullis, so the realised acceptance rate is
    # their mean to within 5 binomial standard errors
    assert run.acceptance_large.shape == run.acceptance_small.shape == (3,)
    assert np.all((run.acceptance_small[lit] > 0) & (run.acceptance_small[lit] <= 1))
    assert np.all((run.acceptance_large[lit] >= 0) & (run.acceptance_large[lit] <= 1))
    assert np.all(np.isnan(run.acceptance_small[~lit]))
    small_only = mmlt_film(scene, (8, 8), 64, rng=3, max_depth=3, chains=128, p_large=0.0)
    assert np.all(np.isnan(small_only.acceptance_large))
    mix = np.nansum(small_only.acceptance_small * small_only.chains) / small_only.chains.sum()
    assert abs(small_only.acceptance_rate - mix) < 5 * np.sqrt(mix * (1 - mix) / (128 * 32))
    # chains per depth follow b_d (largest remainders, one at least per lit depth)
    share = run.b / run.b.sum() * (128 - lit.sum())
    assert np.all(np.abs(run.chains - lit - share) < 1)


@pytest.mark.parametrize("options,error,match", [
    ({"sigma": 0.0}, ValueError, "sigma"),
    ({"sigma": 2.0}, ValueError, "sigma"),
    ({"sigma": float("nan")}, ValueError, "sigma"),
    ({"p_large": 1.5}, ValueError, "p_large"),
    ({"chains": 0}, ValueError, "chains"),
    ({"n_bootstrap": 0}, ValueError, "n_bootstrap"),
    ({"bootstrap": "yes"}, TypeError, "bootstrap"),
    ({"max_depth": 0}, ValueError, "max_depth"),
    ({"chains": 2.5}, TypeError, "chains"),
    ({"direct_depth": -1}, ValueError, "direct_depth"),
    ({"direct_depth": 6}, ValueError, "direct_depth"),
    ({"direct_depth": 1.5}, TypeError, "direct_depth"),
    ({"direct_share": 0.0}, ValueError, "direct_share"),
])
def test_bad_input_names_the_argument(options, error, match):
    with pytest.raises(error, match=match):
        render(load_scene("cornell"), method="mmlt", spp=1, res=4, **options)


def test_too_many_bootstrap_states_is_a_value_error_before_work():
    with pytest.raises(ValueError, match="n_bootstrap"):
        mmlt_film(load_scene("cornell"), (4, 4), 1, settings=MmltSettings(n_bootstrap=2 ** 40))


def test_start_up_bias_is_removed_by_the_bootstrap(cornell):
    """pssmlt's measure (docs/mcmc.md): after one mutation per chain, the share of the image's
    luminance in the reference's darker half of pixels. Chains resampled from the bootstrap agree
    with the reference (within 5 sigma over 6 runs); chains started at uniformly drawn lit states
    over-represent the dark half (measured 0.145 +- 0.004 against 0.099)."""
    ref = render(cornell, method="path", spp=512, res=16, rng=5, max_depth=5).image.reshape(-1, 3) @ LUM
    dark = ref < np.median(ref)
    truth = ref[dark].sum() / ref.sum()
    share = {}
    for boot in (True, False):
        vals = []
        for seed in range(6):
            run = mmlt_film(cornell, (16, 16), 4, rng=seed, max_depth=5, chains=1024, bootstrap=boot,
                            n_bootstrap=4096)
            assert run.n_steps == 1
            img = (run.sum / run.spp) @ LUM
            vals.append(img[dark].sum() / img.sum())
        share[boot] = (np.mean(vals), np.std(vals, ddof=1) / np.sqrt(6))
    assert abs(share[True][0] - truth) < 5 * share[True][1], (share, truth)
    assert share[False][0] - truth > 5 * share[False][1], (share, truth)


def _states(name, depth, seed, res=(8, 8), n=16384):
    """``(ctx, layout, rng, x)``: a BDPT context on scene ``name`` and ``n`` stratified depth-``depth`` states."""
    scene = load_scene(name)
    ctx = _Context(scene, Tracer(scene), LightOrigins(scene), res, "power", True)
    lay = StateLayout(depth)
    rng = np.random.default_rng(seed)
    return ctx, lay, rng, stratified_states(n, lay.dim, res, rng)


@pytest.mark.parametrize("name", ["cornell-door", "cornell-point", "quad-environment", "cornell-caustic"])
def test_bootstrap_values_are_each_strategys_target(name):
    """An exact identity between two evaluations of f_d: ``bootstrap_values`` (one BDPT sample per
    state, full-length subpaths joined in every way) and ``evaluate_states`` (one strategy per state,
    every subpath traced only as long as its strategy needs, all of them in one wavefront). The
    shorter subpaths are prefixes of the longer ones (no Russian roulette), so each state's value
    must be its column's to rounding, on area, point and environment lights and on glass."""
    depth = 4
    ctx, lay, rng, x = _states(name, depth, 2207)
    fb, _ = bootstrap_values(ctx, lay, x, kernel="general")        # BDPT's own code (the kernel: below)
    cols = strategy_columns(depth)
    j = rng.integers(0, len(cols), size=x.shape[0])               # a strategy per state
    d = np.array([cols[i][0] for i in j])
    s = np.array([cols[i][1] for i in j])
    y = x.copy()
    y[:, lay.strategy] = (s + rng.random(x.shape[0]) * (1 - 1e-9)) / (d + 1)
    f, pixel, rgb, _ = evaluate_states(ctx, lay, y, d, kernel="general")
    want = fb[np.arange(x.shape[0]), j]
    assert np.count_nonzero(want) >= 50                           # the identity is not vacuous
    np.testing.assert_allclose(f, want, rtol=1e-12, atol=0.0)
    assert np.all((pixel >= 0) == (f > 0)) and np.allclose(rgb @ LUM, f, rtol=1e-12)
    # and BDPT's estimate of b_d from the columns is the mean of one-strategy states x (d + 1) / (d + 1)
    for dd in range(1, depth + 1):
        mine = [i for i, c in enumerate(cols) if c[0] == dd]
        assert fb[:, mine].min() >= 0.0


@pytest.mark.parametrize("name", ["cornell", "cornell-door", "checkerboard", "furnace"])
def test_lambertian_kernel_is_the_general_evaluation(name):
    """The Lambertian kernel (one vectorised pass over every strategy) against BDPT's own
    connections, state by state: the same f, pixel and rgb to rounding, for single states at every
    depth and strategy and for the bootstrap's every-strategy rows (an exact identity: the same
    paths, the same formulas written out); the checkerboard's textured emitter and the furnace's
    spheres take the kernel's general fallbacks."""
    depth = 5
    ctx, lay, rng, x = _states(name, depth, 2208)
    d = rng.integers(1, depth + 1, size=x.shape[0])
    f, pixel, rgb, _ = evaluate_states(ctx, lay, x, d, kernel="general")
    g, pixel_g, rgb_g, _ = evaluate_states(ctx, lay, x, d, kernel="lambertian", work=Workspace())
    assert np.count_nonzero(f) >= 50
    np.testing.assert_allclose(g, f, rtol=1e-12, atol=0.0)
    np.testing.assert_array_equal(pixel_g, pixel)
    np.testing.assert_allclose(rgb_g, rgb, rtol=1e-12, atol=0.0)
    work = Workspace()
    for _ in range(2):                      # reused buffers (the chains' steps) give the same values
        fb = bootstrap_values(ctx, lay, x[:4096], kernel="lambertian", work=work)[0]
        np.testing.assert_allclose(fb, bootstrap_values(ctx, lay, x[:4096], kernel="general")[0], rtol=1e-12,
                                   atol=0.0)


def test_kernel_option_is_checked():
    with pytest.raises(ValueError, match="kernel"):
        render(load_scene("cornell"), method="mmlt", spp=1, res=4, kernel="fast")
    with pytest.raises(ValueError, match="kernel='lambertian'"):
        render(load_scene("cornell-spheres"), method="mmlt", spp=1, res=4, kernel="lambertian")
    scene = load_scene("cornell")
    kw = dict(method="mmlt", spp=4, res=8, rng=2209, max_depth=3, chains=64, n_bootstrap=2048, batch_spp=4)
    a = render(scene, kernel="general", **kw).image
    b = render(scene, kernel="lambertian", **kw).image
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-15)   # the same chains: the kernel changes no value


def _embed(x, short, long):
    """States of ``StateLayout(long.max_depth)`` whose streams begin with those of ``x`` (``short``)."""
    y = np.random.default_rng(5).random((x.shape[0], long.dim))
    y[:, :2] = x[:, :2]
    for a, b in ((short.camera_vertices, long.camera_vertices), (short.light_vertices, long.light_vertices)):
        y[:, b.start:b.start + a.stop - a.start] = x[:, a]
    y[:, long.light_origin] = x[:, short.light_origin]
    return y


@pytest.mark.parametrize("kernel", ["general", "lambertian"])
def test_direct_part_is_the_bootstraps_short_depths(kernel):
    """An exact identity: the direct part's BDPT sample (subpaths of a depth-2 state) joined in the
    strategies of depths 1, 2 gives each strategy's f, pixel and rgb of the depth-5 bootstrap sample
    whose streams begin with the same numbers (its subpaths are prefixes: no Russian roulette)."""
    scene = load_scene("cornell-door")
    res = (8, 8)
    ctx = _Context(scene, Tracer(scene), LightOrigins(scene), res, "power", True)
    short, long = StateLayout(2), StateLayout(5)
    x = stratified_states(8192, short.dim, res, np.random.default_rng(2210))
    f, pix, rgb, _ = bootstrap_splats(ctx, short, x, kernel, Workspace())
    g, pix_g, rgb_g, _ = bootstrap_splats(ctx, long, _embed(x, short, long), kernel, Workspace())
    n = len(strategy_columns(2))
    assert strategy_columns(5)[:n] == strategy_columns(2) and np.count_nonzero(f) >= 50
    np.testing.assert_allclose(f, g[:, :n], rtol=1e-12, atol=0.0)
    np.testing.assert_array_equal(pix, pix_g[:, :n])
    np.testing.assert_allclose(rgb, rgb_g[:, :n], rtol=1e-12, atol=0.0)
    # and the splat keeps the luminance: the direct image's mean is BDPT's b_1 + b_2 of the same states
    image, _ = _direct_image(ctx, 8192, 2, kernel, Workspace(), np.random.default_rng(2210))
    d = np.array([c[0] for c in strategy_columns(2)])
    np.testing.assert_allclose((image @ LUM).mean(), (f / (d + 1)).sum(axis=1).mean(), rtol=1e-12)


def test_direct_depths_and_chain_depths_partition_the_depths(cornell):
    """direct_depth=2 at max_depth 4: no chain at depths 1, 2, every chain at 3, 4 (in proportion to
    b_d); direct_depth=max_depth: no chain at all, the image BDPT's alone."""
    run = mmlt_film(cornell, (8, 8), 32, rng=4, max_depth=4, chains=128, direct_depth=2)
    assert np.all(run.chains[:2] == 0) and run.chains.sum() == 128 and np.all(run.chains[2:] > 0)
    share = run.b[2:] / run.b[2:].sum() * (128 - 2)
    assert np.all(np.abs(run.chains[2:] - 1 - share) < 1)
    none = mmlt_film(cornell, (8, 8), 32, rng=4, max_depth=4, chains=128, direct_depth=4)
    assert none.chains.sum() == 0 and np.isnan(none.acceptance_rate) and np.all(np.isfinite(none.sum))


@pytest.mark.parametrize("direct_depth", [2, 3])
def test_direct_plus_chains_is_unbiased_against_bdpt_per_block(cornell, direct_depth):
    """direct_depth=2 (BDPT for depths 1, 2, chains for 3) and 3 (every depth by BDPT: the zero-chain
    run) at max_depth 3: block means of independent runs against independent BDPT renders, 5 sigma
    Sidak over the 12 checks (each side's variance from its runs' spread)."""
    res, depth, R = 8, 3, 12
    seeds = np.random.SeedSequence(2211 + direct_depth).spawn(2 * R)

    def blocks(img):
        return img.reshape(2, 4, 2, 4, 3).mean(axis=(1, 3)).reshape(4, 3)

    m = np.array([blocks(render(cornell, method="mmlt", spp=64, res=res, rng=s, max_depth=depth, batch_spp=64,
                                chains=512, direct_depth=direct_depth).image) for s in seeds[:R]])
    b = np.array([blocks(render(cornell, method="bdpt", spp=32, res=res, rng=s, max_depth=depth).image)
                  for s in seeds[R:]])
    se = np.sqrt(m.var(axis=0, ddof=1) / R + b.var(axis=0, ddof=1) / R)
    z = (m.mean(axis=0) - b.mean(axis=0)) / se
    assert np.all(np.abs(z) < _z(z.size)), (z, _z(z.size))


def test_workers_two_give_the_image_of_one_with_a_direct_part():
    scene = load_scene("cornell-door")
    kw = dict(method="mmlt", spp=4, res=8, rng=2212, batch_spp=2, max_depth=4, chains=64, n_bootstrap=4096,
              direct_depth=2)
    np.testing.assert_array_equal(render(scene, workers=1, **kw).image, render(scene, workers=2, **kw).image)


@pytest.mark.parametrize("direct_depth", [0, 2])
def test_depth_split_of_the_image_adds_up_and_scales_by_b(cornell, direct_depth):
    """``MmltFilm.depth_sum`` / ``direct_sum`` (the image split by depth, for the oracle-``b``
    measurement of docs/mcmc.md): they add to ``sum`` to rounding, the chains' depths carry mean
    luminance ``b_d`` each (the estimator's normalisation, exact), and the direct depths nothing."""
    f = mmlt_film(cornell, (8, 8), 16, rng=3, max_depth=4, chains=256, direct_depth=direct_depth)
    np.testing.assert_allclose(f.depth_sum.sum(axis=0) + f.direct_sum, f.sum, rtol=1e-12, atol=1e-15)
    lum = (f.depth_sum / f.spp) @ LUM
    chain = np.arange(1, 5) > direct_depth
    np.testing.assert_allclose(lum.mean(axis=1)[chain], f.b[chain], rtol=1e-9)
    assert np.all(lum[~chain] == 0.0)

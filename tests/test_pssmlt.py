"""PSSMLT (issue 12): agreement with path tracing, consistency, start-up bias; cornell-door."""
import math

import numpy as np
import pytest
from scipy import stats

from mcvar.envmap import LUMINANCE_WEIGHTS
from mcvar.integrators import METHODS, render
from mcvar.integrators.pssmlt import OPTIONS, _path_function, pssmlt_film, state_dim
from mcvar.scene import load_scene
from mcvar.tracer import Tracer


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

"""Unbiased adaptive sampling (mcvar.adaptive): the allocation rule, the
estimator's unbiasedness against uniform ``path`` (5 standard errors), where the
samples go, the seed/worker contract and bad input."""
import numpy as np
import pytest

from mcvar.adaptive import allocate, render_adaptive
from mcvar.integrators import render
from mcvar.scene import load_scene

SEED = 20261201


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


def test_allocation_is_neyman_in_powers_of_two():
    """Two groups of pixels whose sigmas differ by 8: Neyman's n_i ~ sigma_i gives
    counts in the ratio 8 (exactly, powers of two) and the budget is met."""
    sigma = np.r_[np.full(100, 1.0), np.full(10, 8.0)]
    n = allocate(sigma, 100 * 16 + 10 * 128, min_spp=1, max_spp=4096)
    assert set(n[:100]) == {16} and set(n[100:]) == {128}
    assert n.sum() == 100 * 16 + 10 * 128
    # square-root tempering: ratio sqrt(8) rounds to 2^round(1.5) -> 4 (np.rint: 2)
    m = allocate(sigma, 2000, min_spp=1, max_spp=4096, exponent=0.5)
    ratio = m[100] / m[0]
    assert ratio in (2, 4) and m.sum() <= 2000


def test_allocation_respects_bounds_and_budget():
    rng = np.random.default_rng(SEED)
    sigma = rng.lognormal(0, 2, 5000)
    sigma[:50] = 0.0
    n = allocate(sigma, 5000 * 64, min_spp=8, max_spp=1024)
    assert n.min() >= 8 and n.max() <= 1024 and n.sum() <= 5000 * 64
    assert np.all(np.log2(n) == np.round(np.log2(n)))          # powers of two (bounds are too)
    order = np.argsort(sigma)
    assert np.all(np.diff(n[order]) >= 0)                        # more variance, no fewer samples
    assert n.sum() > 0.5 * 5000 * 64                             # the budget is used, not wasted


def test_adaptive_is_unbiased_against_uniform_path(cornell):
    """Per channel, the image mean and the mean over the noisiest pixels (the
    light's edge, where keeping the pilot with weights n0 / (n0 + n_i) would be
    biased) agree with uniform ``path`` within 5 standard errors. The random
    sampler makes samples iid, so the per-pixel variances give exact standard
    errors; pixels are independent; 3 seeds each."""
    res, spp, seeds = 16, 64, 3
    a = [render_adaptive(cornell, spp=spp, res=res, sampler="random", rng=SEED + k) for k in range(seeds)]
    p = [render(cornell, integrator="path", spp=spp, res=res, sampler="random", rng=SEED + 100 + k)
         for k in range(seeds)]
    noisy = np.zeros(res * res, bool)
    noisy[np.argsort(sum(r.variance.mean(axis=2) for r in p).ravel())[-12:]] = True
    for name, mask in {"image": np.ones(res * res, bool), "noisiest pixels": noisy}.items():
        k = int(mask.sum())
        for c in range(3):
            def stat(renders):
                mean = np.mean([r.image.reshape(-1, 3)[mask, c].mean() for r in renders])
                var = np.sum([(r.variance / r.spp).reshape(-1, 3)[mask, c].sum() for r in renders])
                return mean, var / (k * len(renders)) ** 2
            (ma, va), (mp, vp) = stat(a), stat(p)
            z = (ma - mp) / np.sqrt(va + vp)
            assert abs(z) < 5.0, (name, c, ma, mp, z)


def test_samples_go_to_the_light_edge(cornell):
    """The second stage puts its most samples where uniform path's pixels are
    noisiest, and the adaptive image beats uniform random sampling's MSE
    against a shared higher-spp image by more than their noise."""
    a = render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED, visible_lights="sampled")
    counts = a.spp_map
    p = render(cornell, integrator="path", spp=64, res=16, sampler="random", rng=SEED + 1)
    noisy = p.variance.mean(axis=2) > np.quantile(p.variance.mean(axis=2), 0.95)
    assert counts[noisy].mean() > 4 * counts[~noisy].mean()
    # the adaptive estimate's own per-pixel variance of the mean is smaller in total
    assert (a.variance / a.spp).sum() < (p.variance / p.spp).sum()


def test_exact_visible_lights_free_the_light_pixels(cornell):
    """With the light's pixels integrated exactly (the default), the pixels
    the light covers carry only their ceiling's variance: they are no longer
    favoured (about the median count, against 8-16x it when sampled), and
    the samples go to the rest of the image instead."""
    a = render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED)
    s = render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED, visible_lights="sampled")
    light = a.image.max(axis=2) > 1.0                     # radiance 17 inside, ~0.2 elsewhere
    assert light.sum() >= 2
    assert a.spp_map[light].mean() <= 2 * np.median(a.spp_map)
    assert s.spp_map[light].mean() > 4 * a.spp_map[light].mean()
    assert a.spp_map[~light].mean() > s.spp_map[~light].mean()


def test_same_seed_same_image_any_workers(cornell):
    a = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED, workers=1)
    b = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED, workers=2)
    c = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED + 1, workers=1)
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)


def test_two_workers_split_batches_between_the_parent_and_the_pool(cornell, monkeypatch):
    """With ``workers=2`` the caller renders batches too (taken from the queue's end)
    and the pool the others; the image is still that of ``workers=1``."""
    import os

    import mcvar.adaptive as adaptive

    monkeypatch.setattr(adaptive, "PILOT_PATHS_PER_BATCH", 4)       # 64 pilot batches of one pixel (4 spp)
    parent = os.getpid()
    ran = []
    inner = adaptive._pixel_sample_columns          # called once per batch, by whoever runs it

    def counted(*a, **k):
        if os.getpid() == parent:       # forked pool processes count in their own memory
            ran.append(1)
        return inner(*a, **k)

    monkeypatch.setattr(adaptive, "_pixel_sample_columns", counted)
    one = render_adaptive(cornell, spp=64, res=8, sampler="sobol", rng=SEED, workers=1)
    n_batches = len(ran)
    ran.clear()
    two = render_adaptive(cornell, spp=64, res=8, sampler="sobol", rng=SEED, workers=2)
    assert np.array_equal(one.image, two.image)
    assert n_batches > 64
    assert 1 <= len(ran) < n_batches        # the caller worked, and not alone


@pytest.mark.parametrize("kw, match", [
    (dict(spp=0), "spp"),
    (dict(integrator="albedo"), "integrator"),
    (dict(pilot_spp=1), "pilot_spp"),
    (dict(spp=16, pilot_spp=8, min_spp=16), "pilot_spp \\+ min_spp"),
    (dict(sampler="jittered"), "square"),
    (dict(min_spp=64, max_spp=32, spp=256), "max_spp"),
])
def test_bad_input(cornell, kw, match):
    with pytest.raises(ValueError, match=match):
        render_adaptive(cornell, **{"res": 4, **kw})


def test_ctrl_c_keeps_finished_batches_and_falls_back_to_the_pilot(cornell):
    """A KeyboardInterrupt from the progress callback half way through the
    second stage: finished pixels are those of the full render (same seed),
    the others show their pilot mean (spp_map = pilot_spp)."""
    full = render_adaptive(cornell, spp=64, res=16, rng=SEED, pilot_spp=4)
    total = 16 * 16 * 64

    def stop(done, _):
        if done > total // 2:
            raise KeyboardInterrupt

    part = render_adaptive(cornell, spp=64, res=16, rng=SEED, pilot_spp=4, progress=stop)
    assert part.interrupted and not full.interrupted
    finished = part.spp_map >= 8                     # min_spp = 64 // 8 > pilot_spp
    assert 0 < finished.sum() < finished.size
    assert np.array_equal(part.image[finished], full.image[finished])
    assert np.all(part.spp_map[~finished] == 4)
    assert np.all(np.isfinite(part.image)) and part.image[~finished].mean() > 0

"""Unbiased adaptive sampling (mcvar.adaptive): the allocation rule, the
estimator's unbiasedness against uniform ``path`` (5 standard errors), where the
samples go, the seed/worker contract and bad input."""
import numpy as np
import pytest

from pathlib import Path

from mcvar.adaptive import ADAPTIVE_SETTINGS, adaptive_settings, allocate, render_adaptive
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
    noisiest (averaged over three seeds: a 4-spp pilot may miss the light's
    edge in one render), and the adaptive estimate's own per-pixel variance
    of the mean is smaller in total than uniform random sampling's."""
    a = [render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED + k, visible_lights="sampled")
         for k in range(3)]
    counts = np.mean([r.spp_map for r in a], axis=0)
    p = render(cornell, method="path", spp=256, res=16, sampler="random", rng=SEED + 100)
    noisy = p.variance.mean(axis=2) > np.quantile(p.variance.mean(axis=2), 0.95)
    assert counts[noisy].mean() > 4 * counts[~noisy].mean()
    for r in a:
        assert (r.variance / r.spp).sum() < (p.variance / 64).sum()


def test_exact_visible_lights_free_the_light_pixels(cornell):
    """With the light's pixels integrated exactly (the default), the pixels
    the light covers carry only their ceiling's variance: they are no longer
    favoured (about twice the median count, measured 2.2x on average over 16
    seeds, against 8-16x it when sampled), and the samples go to the rest of
    the image instead. Counts averaged over three seeds (a 4-spp pilot whose
    samples all land inside the light sees no edge in one render)."""
    a = [render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED + k) for k in range(3)]
    s = [render_adaptive(cornell, spp=64, res=16, sampler="random", rng=SEED + k, visible_lights="sampled")
         for k in range(3)]
    light = a[0].image.max(axis=2) > 1.0                     # radiance 17 inside, ~0.2 elsewhere
    assert light.sum() >= 2
    ca, cs = np.mean([r.spp_map for r in a], axis=0), np.mean([r.spp_map for r in s], axis=0)
    assert ca[light].mean() <= 3 * np.median(ca)
    assert cs[light].mean() > 2 * ca[light].mean()          # measured 3.9x over four seeds
    assert ca[~light].mean() > cs[~light].mean()


def test_same_seed_same_image_any_workers(cornell):
    a = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED, workers=1)
    b = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED, workers=2)
    c = render_adaptive(cornell, spp=32, res=8, sampler="sobol", rng=SEED + 1, workers=1)
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)


def _path_batch_recording_pid(folder, job):
    """``path``'s run_batch, leaving one file per batch named by the process that ran it."""
    import os
    import uuid

    from mcvar.integrators.path import run_path_batch

    (Path(folder) / f"{os.getpid()}-{uuid.uuid4().hex}").touch()
    return run_path_batch("path", job)


def test_two_workers_split_batches_between_the_parent_and_the_pool(cornell, tmp_path):
    """With ``workers=2`` the caller renders batches too (those no worker has started)
    and the pool the others; the image is still that of ``workers=1``. The method is
    ``path`` with a run_batch that records who ran each batch (a Method object need
    not be registered), and 64 pilot batches of one pixel: no module attribute is patched."""
    import dataclasses
    import os
    from functools import partial

    from mcvar.integrators import METHODS, Adaptive

    def run(workers, folder):
        folder.mkdir()
        method = dataclasses.replace(METHODS["path"], run_batch=partial(_path_batch_recording_pid, str(folder)))
        r = render(cornell, method=method, spp=64, res=8, sampler="sobol", rng=SEED, workers=workers,
                   allocation=Adaptive(pilot_paths_per_batch=4), **ADAPTIVE_SETTINGS)
        pids = [f.name.split("-")[0] for f in folder.iterdir()]
        return r, len(pids), pids.count(str(os.getpid()))

    one, n_batches, _ = run(1, tmp_path / "one")
    two, n_two, by_parent = run(2, tmp_path / "two")
    assert np.array_equal(one.image, two.image)
    assert n_batches == n_two > 64
    assert 1 <= by_parent < n_batches        # the caller worked, and not alone


def test_adaptive_image_is_its_second_stage_alone(cornell):
    """The identity: the adaptive image equals, exactly, the image of its
    second stage rendered alone (``Adaptive(spp_map=...)``: no pilot, the
    same allocation, the same seed), so ``image * spp_map`` is the second
    stage's per-pixel sums and no pilot sample is in it. Averaging the pilot
    into the image (the biased n0 / (n0 + n_i) weights) fails here."""
    from mcvar.integrators import Adaptive

    a = render_adaptive(cornell, spp=64, res=8, sampler="sobol", rng=SEED)
    assert a.pilot_spp > 0 and len(np.unique(a.spp_map)) > 1
    second = render(cornell, spp=64, res=8, sampler="sobol", rng=SEED, allocation=Adaptive(spp_map=a.spp_map),
                    **ADAPTIVE_SETTINGS)
    assert second.pilot_spp == 0 and np.array_equal(second.spp_map, a.spp_map)
    assert np.array_equal(a.image, second.image)
    np.testing.assert_allclose(a.image * a.spp_map[..., None], second.image * second.spp_map[..., None],
                               rtol=0, atol=0)


@pytest.mark.parametrize("method", ["path", "direct", "path_bsdf"])
def test_render_with_adaptive_allocation_is_render_adaptive(cornell, method):
    """``render(..., allocation='adaptive')`` with the adaptive settings is
    ``render_adaptive``: one driver, one image for one seed (and the alias
    ``integrator=`` names the same method)."""
    a = render_adaptive(cornell, integrator=method, spp=32, res=8, rng=SEED)
    b = render(cornell, method=method, spp=32, res=8, sampler="sobol", rng=SEED, allocation="adaptive",
               **adaptive_settings(method))
    assert np.array_equal(a.image, b.image) and np.array_equal(a.spp_map, b.spp_map)
    assert a.method == b.method == method


def test_huge_renders_are_refused_before_allocating(cornell):
    """res = 10^6 (10^12 pixels) is refused by the render's memory guard, adaptive
    or uniform, before any array is made (tracemalloc sees under 10 MB)."""
    import tracemalloc

    tracemalloc.start()
    try:
        for call in (lambda: render_adaptive(cornell, res=10 ** 6),
                     lambda: render(cornell, res=10 ** 6, allocation="adaptive"),
                     lambda: render(cornell, res=10 ** 6)):
            with pytest.raises(ValueError, match="max_memory"):
                call()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10 * 2 ** 20


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


def test_pilot_batches_grow_with_a_large_pilot():
    """Pilot batches of PILOT_PATHS_PER_BATCH until the pilot fills PILOT_BATCHES of
    them (64 x 64 at 256 spp keeps its batches), then PILOT_BATCHES batches, never
    more than PATHS_PER_BATCH paths."""
    from mcvar.integrators.allocation import PATHS_PER_BATCH, PILOT_BATCHES, PILOT_PATHS_PER_BATCH, \
        pilot_batch_paths

    assert pilot_batch_paths(64 * 64 * 8) == PILOT_PATHS_PER_BATCH == 4096
    assert pilot_batch_paths(16) == PILOT_PATHS_PER_BATCH
    assert pilot_batch_paths(256 * 256 * 4) == 256 * 256 * 4 // PILOT_BATCHES == 32768
    assert pilot_batch_paths(2 ** 39) == PATHS_PER_BATCH


def test_larger_pilot_batches_stay_unbiased(cornell):
    """128 x 128 at 16 spp: the pilot's 65,536 paths in 8 batches of 8,192 (the
    default) instead of 16 of 4,096 (before): another pilot, another allocation,
    the same expectation. Per channel, the image means over all pixels and off
    the light's pixels agree within 5 standard errors (independent seeds), and
    the two renders did allocate differently (the test compares two estimators,
    not one twice)."""
    from mcvar.integrators import VisibleLights
    from mcvar.integrators.allocation import PILOT_PATHS_PER_BATCH, Adaptive

    res, spp = 128, 16
    new = render_adaptive(cornell, spp=spp, res=res, rng=SEED)
    old = render(cornell, spp=spp, res=res, sampler="sobol", rng=SEED + 1,
                 allocation=Adaptive(pilot_paths_per_batch=PILOT_PATHS_PER_BATCH), **ADAPTIVE_SETTINGS)
    same_seed_old = render(cornell, spp=spp, res=res, sampler="sobol", rng=SEED,
                           allocation=Adaptive(pilot_paths_per_batch=PILOT_PATHS_PER_BATCH), **ADAPTIVE_SETTINGS)
    assert not np.array_equal(new.spp_map, same_seed_old.spp_map)
    lit = VisibleLights(cornell).image((res, res))[:, 0] > 0
    for mask in (np.ones(res * res, bool), ~lit):
        d = (new.image - old.image).reshape(-1, 3)[mask]
        v = (new.standard_error ** 2 + old.standard_error ** 2).reshape(-1, 3)[mask]
        k = mask.sum()
        assert np.all(np.abs(d.mean(axis=0)) < 5 * np.sqrt(v.sum(axis=0)) / k)

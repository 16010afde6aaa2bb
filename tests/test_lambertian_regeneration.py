"""The Lambertian kernel's path regeneration (:mod:`mcvar.integrators.lambertian`):
a batch traced through a wavefront of fewer slots than paths, finished paths'
slots refilled with new camera paths, so that one wavefront holds paths at
different depths.

Exact identities first: when every number a path reads comes from its row of
``u`` the radiance of every path does not depend on the number of slots, bit for
bit. Then statistics: regenerated renders against the general loop (which never
regenerates) per channel within Z = 5 standard errors, Sidak-corrected over the
tests of this file (iid ``random`` sampler: per-pixel variances give exact
standard errors; Sobol' renders over independent seeds, Student's t). The polar
cosine warp the kernel uses for iid numbers: its exact formula and a chi-square
test against the cosine density.
"""
import numpy as np
import pytest
from scipy import stats

from mcvar.adaptive import render_adaptive
from mcvar.integrators import lambertian, render, stream_dim, trace_camera_paths
from mcvar.integrators.allocation import MAIN_BATCHES, MAIN_PATHS_PER_BATCH, PATHS_PER_BATCH, main_batch_paths
from mcvar.scene import load_scene
from mcvar.testing import chi2_test, sidak_significance
from mcvar.warps import _cosine_hemisphere_polar_unchecked, square_to_cosine_hemisphere_pdf

SEED = 20261202
#: the statistical comparisons below (tests x channels): a family-wise two-sided
#: 5-sigma level, Sidak-corrected over them (per comparison |z| < 5.6)
N_STAT = 7 * 3
ALPHA = sidak_significance(2 * stats.norm.sf(5.0), N_STAT)
Z = stats.norm.isf(ALPHA / 2)


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


@pytest.fixture
def few_slots(monkeypatch):
    """A wavefront of 256 slots (refilled below 128), and a count of the refills."""
    calls = []
    refill = lambertian._refill

    def counting(*a):
        calls.append(a[3] - a[2])
        return refill(*a)
    monkeypatch.setattr(lambertian, "WAVEFRONT_PATHS", 256)
    monkeypatch.setattr(lambertian, "_refill", counting)
    return calls


# -- exact identities ----------------------------------------------------------

@pytest.mark.parametrize("method,depth", [("path", 5), ("path", 3), ("path_bsdf", 4), ("direct", None)])
def test_regeneration_changes_no_path_when_u_holds_every_number(cornell, method, depth):
    """With ``u`` as wide as the deepest path reads (stream_dim), every path is a
    pure function of its row: 300 slots refilled many times give every path the
    radiance it gets in one wavefront of all 6,000, exactly, and the same rays.
    (A new path reading another row's numbers, a refilled slot starting with a
    stale throughput or pdf, or a depth counted per wavefront fails here.)"""
    rng = np.random.default_rng(SEED)
    n = 6000
    pixel = rng.integers(0, 16 * 16, n)
    width = stream_dim(depth if depth is not None else 2)
    u = rng.random((n, width))
    kw = dict(max_depth=depth) if depth is not None else {}
    whole, rays_whole = trace_camera_paths(cornell, (16, 16), pixel, u, rng=1, method=method, **kw)
    calls = []
    refill = lambertian._refill

    def small(tr, o, d):
        lambertian.trace_lambertian(tr, o, d, slots=300)
    from mcvar.integrators import path as P
    orig = P.trace_lambertian
    try:
        P.trace_lambertian = small
        lambertian._refill = lambda *a: calls.append(a) or refill(*a)
        part, rays_part = trace_camera_paths(cornell, (16, 16), pixel, u, rng=2, method=method, **kw)
    finally:
        P.trace_lambertian = orig
        lambertian._refill = refill
    assert len(calls) >= 10                     # the slots were refilled: paths of different depths met
    np.testing.assert_array_equal(part, whole)
    assert rays_part == rays_whole


@pytest.mark.parametrize("width", [6, 20, 0])
def test_rows_read_their_own_vertex_columns(width):
    """The kernel's per-row stream (``_VertexColumns``): a wavefront of one depth
    gets exactly :meth:`SampleStream.vertex`'s numbers (the same ``u`` columns, the
    same ``rng`` draws), and in a mixed wavefront every row whose vertex ``u``
    covers gets its own vertex's columns; the rest are fresh uniforms."""
    from mcvar.integrators.lambertian import _VertexColumns
    from mcvar.integrators.stream import BSDF, LIGHT, ROULETTE, SampleStream
    rng = np.random.default_rng(SEED + 2)
    n = 500
    u = rng.random((n, width)) if width else None
    idx = rng.permutation(n)[:300]
    for k in (1, 2, 3, 4):
        for off, cnt in ((LIGHT, 2), (BSDF, 2), (ROULETTE, 1)):
            one, two = SampleStream(u, np.random.default_rng(7)), SampleStream(u, np.random.default_rng(7))
            depth = np.full(idx.size, k)
            got = _VertexColumns(one, depth, 0 if k == 1 else idx.size).vertex(None, off, cnt, idx, np.float32)
            np.testing.assert_array_equal(got, two.vertex(k, off, cnt, idx, np.float32))
    # mixed: rows 0..199 older paths at vertices 2-4, rows 200.. new camera paths (vertex 1)
    depth = np.r_[rng.integers(2, 5, 200), np.ones(100, dtype=np.int64)]
    s = SampleStream(u, np.random.default_rng(8))
    for off, cnt in ((LIGHT, 2), (BSDF, 2), (ROULETTE, 1)):
        got = _VertexColumns(s, depth, 200).vertex(None, off, cnt, idx, np.float32)
        assert got.shape == (cnt, 300) and np.all((got >= 0) & (got <= 1))
        for k in (1, 2, 3, 4):
            rows = np.flatnonzero(depth == k)
            col = 2 + 6 * (k - 1) + off
            if u is not None and col + cnt <= width:
                np.testing.assert_array_equal(got[:, rows], u[idx[rows], col:col + cnt].T.astype(np.float32))
            elif u is None or col >= width:
                assert np.unique(got[:, rows]).size > 0.99 * got[:, rows].size    # iid draws, not a copy


# -- statistics ------------------------------------------------------------------

def _lower_mean_se(r):
    """Per channel, the mean over rows 4.. of a 16 x 16 image (below the light's
    0-or-17 edge pixels) and its standard error from the per-pixel variances."""
    img, var = r.image[4:], r.variance[4:]
    n = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1)) / r.spp) / n


@pytest.mark.parametrize("kw", [dict(), dict(rr_threshold=0.2, rr_depth=2), dict(max_depth=3),
                                dict(integrator="path_bsdf"), dict(integrator="direct_light")],
                         ids=["path", "window", "depth3", "path_bsdf", "direct_light"])
def test_regenerated_wavefront_agrees_with_the_general_loop(cornell, few_slots, kw):
    """16 x 16 at 64 spp (16,384 paths through 256 slots, the random sampler: every
    row iid, the polar warp everywhere) against the general loop: per channel within
    Z combined standard errors."""
    kw = dict(kw)
    integrator = kw.pop("integrator", "path")
    a = render(cornell, integrator=integrator, spp=64, res=16, rng=SEED + 10, kernel="lambertian", **kw)
    assert len(few_slots) >= 50
    b = render(cornell, integrator=integrator, spp=64, res=16, rng=SEED + 11, kernel="general", **kw)
    (ma, sa), (mb, sb) = _lower_mean_se(a), _lower_mean_se(b)
    assert np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb)), (ma, mb, sa, sb)


def test_adaptive_sobol_default_regenerated_agrees_with_the_general_loop(cornell, few_slots):
    """``mcvar render``'s estimator (render_adaptive, Sobol': new paths' first
    vertex from the sampler through the concentric map, the rest iid through the
    polar one) with 256 slots, against the general loop, over R = 10 independent
    seeds each: the image means (every pixel, the exact light image included) by
    Welch's t at the 5-sigma level."""
    R = 10
    seeds = np.random.SeedSequence(SEED + 20).spawn(2 * R)

    def means(kernel, ss):
        return np.array([render_adaptive(cornell, spp=32, res=16, rng=s, kernel=kernel).image.mean(axis=(0, 1))
                         for s in ss])
    a = means("lambertian", seeds[:R])
    assert len(few_slots) >= 20
    b = means("general", seeds[R:])
    t, p = stats.ttest_ind(a, b, axis=0, equal_var=False)
    assert np.all(p > ALPHA), (a.mean(0), b.mean(0), t, p)


def test_two_workers_give_the_image_of_one_with_regeneration(cornell, few_slots):
    """The image is a function of the seed with refilled wavefronts too."""
    a = render_adaptive(cornell, spp=32, res=16, rng=SEED + 30, workers=1)
    b = render_adaptive(cornell, spp=32, res=16, rng=SEED + 30, workers=2)
    assert len(few_slots) >= 20
    assert np.array_equal(a.image, b.image)


# -- the polar cosine warp ----------------------------------------------------------

def test_polar_cosine_warp_is_its_formula_and_has_the_cosine_density():
    rng = np.random.default_rng(SEED + 40)
    u = rng.random((2, 10_000), dtype=np.float32)
    x, y, z = _cosine_hemisphere_polar_unchecked(u[0], u[1])
    assert x.dtype == y.dtype == z.dtype == np.float32
    u64 = u.astype(np.float64)
    np.testing.assert_allclose(y, np.sqrt(1.0 - u64[0]), atol=3e-7)
    np.testing.assert_allclose(x * x + z * z, u64[0], atol=3e-7)
    phi = np.mod(np.arctan2(z.astype(np.float64), x.astype(np.float64)), 2 * np.pi) / (2 * np.pi)
    far = np.minimum(np.abs(phi - u64[1]), 1.0 - np.abs(phi - u64[1]))   # azimuth on the circle
    assert np.all(far[u64[0] > 1e-6] < 1e-5)

    def sample(uu):
        a = np.asarray(uu, dtype=np.float32)
        return np.stack(_cosine_hemisphere_polar_unchecked(a[:, 0], a[:, 1]), axis=-1).astype(np.float64)
    r = chi2_test(sample, square_to_cosine_hemisphere_pdf, "hemisphere", n=200_000,
                  rng=np.random.default_rng(SEED + 41), significance=1e-3)
    assert r.passed, r.message


# -- batches of the second stage ----------------------------------------------------

def test_second_stage_batches_grow_with_the_render_but_stay_many():
    assert main_batch_paths(64 * 64 * 256) == PATHS_PER_BATCH             # unchanged up to 2^20 paths
    assert main_batch_paths(128 * 128 * 256) == MAIN_PATHS_PER_BATCH
    assert main_batch_paths(256 * 256 * 64) == MAIN_PATHS_PER_BATCH
    assert main_batch_paths(1) == PATHS_PER_BATCH
    for paths in (2 ** 21, 3 * 2 ** 20 + 5, 2 ** 22, 2 ** 30):
        per = main_batch_paths(paths)
        assert per & (per - 1) == 0 and PATHS_PER_BATCH <= per <= MAIN_PATHS_PER_BATCH
        if per > PATHS_PER_BATCH:                   # grown: still MAIN_BATCHES batches at least ...
            assert paths // per >= MAIN_BATCHES
        if per < MAIN_PATHS_PER_BATCH:              # ... and as large as that allows
            assert paths // (2 * per) < MAIN_BATCHES


def test_only_renders_the_regenerating_kernel_traces_get_the_larger_batches(cornell):
    """The second stage's batch size resolved by Adaptive.check: the Cornell box at
    128 x 128, 256 spp (the Lambertian kernel) gets MAIN_PATHS_PER_BATCH; the same
    render through the general loop, a scene the kernel cannot trace, a method that
    is not path tracing, and a small render keep PATHS_PER_BATCH; an explicit value wins."""
    from mcvar.integrators import METHODS, Adaptive
    from mcvar.integrators.driver import _plan

    def per(scene, method="path", spp=256, res=128, allocation=None, **kw):
        _, a = _plan(scene, METHODS[method], spp, res, "sobol", allocation or Adaptive(), kw)
        return a.paths_per_batch
    assert per(cornell) == MAIN_PATHS_PER_BATCH
    assert per(cornell, kernel="general") == PATHS_PER_BATCH
    assert per(load_scene("cornell-spheres")) == PATHS_PER_BATCH
    assert per(cornell, method="photon") == PATHS_PER_BATCH
    assert per(cornell, res=64) == PATHS_PER_BATCH
    assert per(cornell, allocation=Adaptive(paths_per_batch=4096)) == 4096
    with pytest.raises(ValueError, match="paths_per_batch"):
        Adaptive(paths_per_batch=0)


# -- the second stage's last batch, cut in TAIL_SPLIT -----------------------------

@pytest.mark.parametrize("sizes,per", [((1000, 50000), 8192), ((3, 40, 90), 16), ((7,), 64), ((100, 1), 7)])
def test_the_tail_split_keeps_every_pixel_whole_in_one_batch(sizes, per):
    """The cut of the second stage's last batches (a batch's worth of paths) into
    TAIL_SPLIT pieces (allocation._level_specs): the same pixels with the same
    samples in the same order, every piece inside one batch of the uncut
    stage, so each pixel keeps all its n samples in one batch (its estimate has
    the distribution it had before the cut); the batches before the cut
    unchanged, and the cut batches at most a TAIL_SPLIT-th of their batch."""
    from mcvar.integrators.allocation import TAIL_SPLIT, _count_level_specs, _level_specs

    rng = np.random.default_rng(SEED + 40)
    pix = rng.permutation(sum(sizes))
    ns = [2 ** (len(sizes) + 2 - i) for i in range(len(sizes))]          # most samples first
    levels = [(n, pix[a - k:a]) for n, k, a in zip(ns, sizes, np.cumsum(sizes))]
    batch = per * ns[-1]
    old, new = list(_level_specs(levels, batch)), list(_level_specs(levels, batch, TAIL_SPLIT))
    assert len(new) == _count_level_specs(levels, batch, TAIL_SPLIT) and len(old) == _count_level_specs(levels, batch)

    def flat(specs):
        return (np.concatenate([s.pixels for s in specs]), np.concatenate([np.full(s.pixels.size, s.spp) for s in specs]))
    for x, y in zip(flat(old), flat(new)):
        assert np.array_equal(x, y)
    edges_old = set(np.cumsum([s.pixels.size for s in old]))
    edges_new = set(np.cumsum([s.pixels.size for s in new]))
    assert edges_old <= edges_new                                      # no piece crosses a batch boundary
    k = len(old)
    while k and sum(s.pixels.size * s.spp for s in old[k:]) < batch:
        k -= 1
    assert all(np.array_equal(a.pixels, b.pixels) and a.spp == b.spp for a, b in zip(old[:k], new[:k]))  # as they were
    for parent in old[k:]:
        pieces = [s for s in new[k:] if np.shares_memory(s.pixels, parent.pixels)]
        assert len(pieces) == min(TAIL_SPLIT, parent.pixels.size)
        assert max(s.pixels.size for s in pieces) <= -(-parent.pixels.size // TAIL_SPLIT)
    assert sum(s.pixels.size * s.spp for s in old[k:]) >= min(batch, sum(n * m for n, m in zip(ns, sizes)))


def test_the_tail_split_render_agrees_with_uncut_batches(cornell, monkeypatch):
    """render_adaptive with the last batch cut (TAIL_SPLIT) against the batches
    before the change (TAIL_SPLIT = 1), R = 10 independent seeds each, batches
    of 2,048 paths (the cut applies to the last 2,048 paths of 8,192): the image means by Welch's t at the
    5-sigma level."""
    from mcvar.adaptive import ADAPTIVE_SETTINGS
    from mcvar.integrators import Adaptive, allocation

    R = 10
    seeds = np.random.SeedSequence(SEED + 50).spawn(2 * R)

    def means(ss):
        return np.array([render(cornell, spp=32, res=16, sampler="sobol", rng=s, allocation=Adaptive(paths_per_batch=2048),
                                **ADAPTIVE_SETTINGS).image.mean(axis=(0, 1)) for s in ss])
    a = means(seeds[:R])
    monkeypatch.setattr(allocation, "TAIL_SPLIT", 1)
    b = means(seeds[R:])
    t, p = stats.ttest_ind(a, b, axis=0, equal_var=False)
    assert np.all(p > ALPHA), (a.mean(0), b.mean(0), t, p)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_the_kernels_triangle_tables_are_built_once_per_render_in_its_precision(cornell, monkeypatch, tmp_path,
                                                                                 precision):
    """The per-triangle tables (frames, albedo, f Le) are kept on the scene
    tables: built once for a render of several batches and two workers (in
    the parent, before the worker forks: ``Method.warm``), in the tracer's
    precision, read-only, and holding each triangle's own normal and albedo."""
    import os

    built, log = [], tmp_path / "builds"
    build = lambertian._build_tables

    def counting(tables, dt):              # a worker process's builds reach the log file
        out = build(tables, dt)
        built.append((os.getpid(), dt, out))
        with open(log, "a") as fh:
            fh.write(f"{os.getpid()}\n")
        return out
    monkeypatch.setattr(lambertian, "_build_tables", counting)
    res, spp = 64, 2 * PATHS_PER_BATCH // (64 * 64)          # two batches
    r = render(cornell, spp=spp, res=res, sampler="random", rng=SEED, precision=precision, max_depth=3)
    assert r.spp == spp and len(built) == 1
    pid, dt, (frame9, albedo, f_le, black) = built[0]
    assert pid == os.getpid() and dt == np.dtype(precision) and frame9.dtype == np.dtype(precision)
    assert not any(a.flags.writeable for a in (frame9, albedo, f_le, black))
    from mcvar.tracer import Tracer
    normal = Tracer(cornell, dtype=precision).triangle_normal.T                 # (3, T), unflipped
    np.testing.assert_allclose(frame9[3:6], normal, rtol=0, atol=4 * np.finfo(precision).eps)
    mat = np.asarray(cornell.prim_material)
    for mi, m in enumerate(cornell.materials):
        np.testing.assert_array_equal(albedo[:, mat == mi], np.broadcast_to(m.albedo[:, None], (3, int((mat == mi).sum()))))
    assert np.array_equal(black, ~np.any(albedo > 0, axis=0))
    # two workers: the forked worker inherits the parent's tables (no build in the worker, none in a batch)
    log.unlink()
    r2 = render(cornell, spp=spp, res=res, sampler="random", rng=SEED, precision=precision, max_depth=3, workers=2)
    assert log.read_text().split() == [str(os.getpid())]
    np.testing.assert_array_equal(r2.image, r.image)

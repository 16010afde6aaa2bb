"""The MIS triptych on ``veach-mis`` (issue 21; Veach 1997, fig. 9.2).

Per plate (and per plate x light column) MSE of ``direct_bsdf``,
``direct_light`` and ``direct`` (MIS, power heuristic) at equal spp against a
2048-spp ``direct`` reference: BSDF sampling wins where the largest light
meets the sharpest plate, light sampling on the roughest plate, and MIS is
never worse than the better of the two by more than noise (the standard
error of each MSE over its pixels, Sidak-corrected over every comparison).
"""
import numpy as np
import pytest
from scipy.stats import binomtest, norm

from mcvar.integrators import render
from mcvar.scene import load_scene
from mcvar.testing import sidak_significance
from mcvar.tracer import Tracer

RES = (64, 48)
SPP = 16
REF_SPP = 2048
SEED = 21_1997
METHODS = ("direct_bsdf", "direct_light", "direct")


def _regions(scene):
    """Pixel masks: plate ``k`` (0 sharpest, top) x light column ``j`` (0: the
    largest light's reflection; the camera's right is world -x)."""
    w, h = RES
    pix = np.arange(w * h)
    d = scene.camera.ray_directions(RES, pix, np.full((pix.size, 2), 0.5))
    hit = Tracer(scene).intersect(np.broadcast_to(scene.camera.position, (pix.size, 3)), d)
    plate = np.where(hit.prim < 8, hit.prim // 2, -1).reshape(h, w)
    col = np.broadcast_to((np.arange(w) * 4) // w, (h, w))
    return plate, col


@pytest.fixture(scope="module")
def triptych():
    scene = load_scene("veach-mis")
    seeds = np.random.SeedSequence(SEED).spawn(len(METHODS) + 1)
    ref = np.asarray(render(scene, integrator="direct", spp=REF_SPP, res=RES, rng=seeds[0]).image)
    err = {m: ((np.asarray(render(scene, integrator=m, spp=SPP, res=RES, rng=s).image) - ref) ** 2).mean(axis=2)
           for m, s in zip(METHODS, seeds[1:])}
    return scene, err, _regions(scene), ref.mean(axis=2)


def _mse(e, mask):
    v = e[mask]
    return v.mean(), v.std(ddof=1) / np.sqrt(v.size)


def test_each_single_strategy_wins_somewhere_and_mis_is_never_worse(triptych):
    scene, err, (plate, col), ref = triptych
    regions = [plate == k for k in range(4)] + [(plate == k) & (col == j) for k in range(4) for j in range(4)]
    assert all(r.sum() >= 20 for r in regions)
    z = norm.isf(sidak_significance(1e-3, len(regions) + 2))
    table = np.array([[_mse(err[m], r) for m in METHODS] for r in regions])    # (R, 3, 2)
    # light sampling wins on the roughest plate, BSDF sampling where the largest
    # light meets the sharpest plate. BSDF sampling's squared errors on a rough
    # plate are heavy-tailed (a rare hit of a small, bright light), so the MSE's
    # standard error is too wide to rank them: a paired sign test per pixel
    # instead (which strategy's error is smaller, binomial against 1/2)
    alpha = sidak_significance(1e-3, len(regions) + 2)
    cell = (plate == 0) & (col == 0)
    highlight = cell & (ref > 0.1 * ref[cell].max())       # the largest light's reflection on the sharpest plate
    for win, lose, mask in (("direct_light", "direct_bsdf", plate == 3), ("direct_bsdf", "direct_light", highlight)):
        better = int(np.sum(err[win][mask] < err[lose][mask]))
        assert binomtest(better, int(mask.sum()), 0.5, alternative="greater").pvalue < alpha, (win, better, mask.sum())
        assert _mse(err[win], mask)[0] < _mse(err[lose], mask)[0]
    for r, row in enumerate(table):
        best = int(np.argmin(row[:2, 0]))
        (mis, s_mis), (bst, s_best) = row[2], row[best]
        assert mis - bst <= z * np.hypot(s_mis, s_best), (r, row)


def test_the_lights_have_equal_power_and_are_sampled_lights():
    scene = load_scene("veach-mis")
    n_tri = scene.n_triangles
    radiance = scene.prim_emission[n_tri:, 0]
    power = 4 * np.pi ** 2 * scene.sphere_radii ** 2 * radiance
    np.testing.assert_allclose(power, power[0], rtol=1e-12)
    assert scene.n_sphere_lights == 4
    np.testing.assert_array_equal(scene.prim_light[n_tri:], np.arange(4))
    assert np.all(np.diff(scene.sphere_radii) > 0)

"""``cornell-caustic`` (issue 21): a caustic path tracing finds only by chance.

The glass sphere under a light of 1/100 the Cornell area focuses it on the
floor. Path tracing reaches those pixels only when a floor bounce refracts
through the sphere onto the small light; BDPT's light subpaths start on the
light and connect the refracted vertex to the camera side.

* Agreement. Path tracing's samples on this scene are heavy-tailed
  everywhere (a rare refracted hit of the radiance-1700 light lights the
  caustic, and the caustic lights the whole room), so at any affordable spp
  its standard error is no yardstick (measured: 256-spp image means 0.133
  and 0.153 from two seeds, BDPT's 0.1345-0.1350). So: ``bdpt`` agrees with
  ``light`` tracing (an independent estimator, exact for every pixel whose
  camera ray first hits a diffuse surface) on the pixels that see neither
  the glass sphere nor the light; and ``bdpt`` agrees with ``path`` on the
  same room with the full-size light (``light_scale=1``), where path
  tracing is not heavy-tailed. Image mean (5 sigma) and every 4 x 4 block
  (Sidak over the blocks), z-scores from the per-pixel standard errors.
* Variance at equal spp on the caustic's floor pixels: the expected MSE
  of a 32-spp render, ``variance / 32``, path tracing's (from one 4096-spp
  render: its per-sample variance is carried by rare hits of the light
  through the glass) more than 1000x BDPT's upper 5-sigma bound, a test of
  level 1e-3 by Markov's inequality whatever path's tail; and a 32-spp
  BDPT render's squared error below path's expected MSE.
"""
import numpy as np
import pytest
from scipy import ndimage
from scipy.stats import norm

from mcvar.experiments.slide_pairs import caustic_pixels
from mcvar.integrators import render
from mcvar.scene import load_scene
from mcvar.testing import sidak_significance
from mcvar.tracer import Tracer

from pixel_rays import subpixel_hits  # tests/pixel_rays.py

SEED = 21_2112
RES = 32
BLOCK = 4
SPP = 32
PATH_SPP = 4096           # path's per-sample variance on the caustic, from enough rare hits


def caustic_mask(scene):
    """The caustic's pixels at this file's resolution (:func:`mcvar.experiments.slide_pairs.caustic_pixels`)."""
    return caustic_pixels(scene, RES)


def test_the_light_is_a_hundredth_of_the_area_at_the_same_power():
    small, cornell = load_scene("cornell-caustic"), load_scene("cornell")
    np.testing.assert_allclose(small.light_area * 100, cornell.light_area, rtol=1e-12)
    np.testing.assert_allclose(small.light_area[:, None] * small.light_radiance,
                               cornell.light_area[:, None] * cornell.light_radiance, rtol=1e-12)
    np.testing.assert_allclose(small.light_origin + 0.5 * (small.light_edge1 + small.light_edge2),
                               cornell.light_origin + 0.5 * (cornell.light_edge1 + cornell.light_edge2))
    lit = small.prim_light >= 0
    np.testing.assert_allclose(small.prim_emission[lit], np.broadcast_to(small.light_radiance[0], (lit.sum(), 3)))
    with pytest.raises(ValueError, match="light_scale"):
        load_scene("cornell-caustic", light_scale=1.5)


def sees_light(scene, sub=8):
    """Pixels whose ``sub x sub`` subpixel rays hit the light, grown by one
    pixel (slivers of the light's edge): their samples carry the light's
    radiance over a tiny area, heavy-tailed at a few spp."""
    pix, hit = subpixel_hits(scene, RES, sub)
    lit = np.zeros(RES * RES, bool)
    lit[pix[np.take(np.append(scene.prim_light, -1), hit.prim) >= 0]] = True
    return ndimage.binary_dilation(lit.reshape(RES, RES), iterations=1)


def _stats(scene, method, spp, seed):
    r = render(scene, integrator=method, spp=spp, res=RES, rng=seed, batch_spp=max(1, spp // 16))
    return np.asarray(r.image).mean(axis=2), np.asarray(r.standard_error).mean(axis=2)


@pytest.fixture(scope="module")
def renders():
    scene = load_scene("cornell-caustic")
    big = load_scene("cornell-caustic", light_scale=1.0)
    seeds = np.random.SeedSequence(SEED).spawn(7)
    out = dict(path=_stats(scene, "path", PATH_SPP, seeds[0]),
               bdpt=_stats(scene, "bdpt", SPP, seeds[1]),
               light=_stats(scene, "light", 4 * SPP, seeds[2]),
               ref=_stats(scene, "bdpt", 256, seeds[3]),
               big_path=_stats(big, "path", 8 * SPP, seeds[4]), big_bdpt=_stats(big, "bdpt", SPP, seeds[5]))
    return scene, out


def _agree(a, sa, b, sb, keep):
    """z of the mean over ``keep`` and the largest block z (blocks wholly in ``keep``)
    against its Sidak limit. The channel mean's standard error is bounded by the
    mean of the channels' (Cauchy-Schwarz): conservative."""
    n = keep.sum()
    z_mean = (a[keep].mean() - b[keep].mean()) / np.sqrt(((sa[keep] ** 2).sum() + (sb[keep] ** 2).sum()) / n ** 2)
    h = RES // BLOCK
    whole = keep.reshape(h, BLOCK, h, BLOCK).all(axis=(1, 3))

    def blocks(x, sq=False):
        y = (x ** 2 if sq else x).reshape(h, BLOCK, h, BLOCK).sum(axis=(1, 3)) / BLOCK ** 2
        return np.sqrt(y) / BLOCK if sq else y
    z = ((blocks(a) - blocks(b)) / np.hypot(blocks(sa, True), blocks(sb, True)))[whole]
    return z_mean, np.abs(z).max(), norm.isf(0.5 * sidak_significance(1e-3, z.size)), z.size


def test_bdpt_agrees_with_light_tracing_off_the_sphere(renders):
    scene, out = renders
    pix = np.arange(RES * RES)
    d = scene.camera.ray_directions((RES, RES), pix, np.full((pix.size, 2), 0.5))
    hit = Tracer(scene).intersect(np.broadcast_to(scene.camera.position, d.shape), d)
    sphere = (hit.prim == scene.n_triangles).reshape(RES, RES)
    sphere = ndimage.binary_dilation(sphere, iterations=1)              # pixels partly covered by it
    keep = ~sphere & ~sees_light(scene)
    z_mean, z_max, limit, blocks = _agree(*out["bdpt"], *out["light"], keep)
    assert blocks >= 20
    assert abs(z_mean) < 5.0 and z_max < limit, (z_mean, z_max, limit)


def test_bdpt_agrees_with_path_under_the_full_size_light(renders):
    scene, out = renders
    keep = ~sees_light(load_scene("cornell-caustic", light_scale=1.0))
    z_mean, z_max, limit, blocks = _agree(*out["big_path"], *out["big_bdpt"], keep)
    assert blocks >= 40
    assert abs(z_mean) < 5.0 and z_max < limit, (z_mean, z_max, limit)


def test_bdpt_has_lower_variance_on_the_caustic_at_equal_spp(renders):
    """The expected MSE of a ``SPP``-sample render, ``variance / SPP`` per pixel
    (both unbiased), averaged over the caustic's pixels. Path tracing's
    per-sample variance there is carried by rare hits of the light through
    the glass (a sample of about 1200 for a pixel worth 0.1-0.3), so it is
    estimated from one 4096-spp render; BDPT's from its 256-spp reference
    render (standard error over pixels)."""
    scene, out = renders
    caustic = caustic_mask(scene)
    assert 30 <= caustic.sum() <= RES * RES // 8
    v_path = (out["path"][1] ** 2 * PATH_SPP)[caustic] / SPP
    v_bdpt = (out["ref"][1] ** 2 * 256)[caustic] / SPP
    # BDPT's estimate is well behaved: its upper bound is b + 5 SE. Path's is an
    # average of rare spikes, whose standard error says nothing; but it is an
    # unbiased, non-negative estimate, so if path's true value were <= that bound,
    # Markov's inequality gives P(estimate >= bound / alpha) <= alpha, whatever
    # its tail: the test below has level alpha = 1e-3 with no normal law assumed
    b, sb = v_bdpt.mean(), v_bdpt.std(ddof=1) / np.sqrt(v_bdpt.size)
    p = v_path.mean()
    assert p * 1e-3 > b + 5.0 * sb, (p, b, sb)
    # and a render of each at that spp: BDPT's squared error against the reference is the smaller
    e_bdpt = ((out["bdpt"][0] - out["ref"][0]) ** 2)[caustic]
    assert e_bdpt.mean() < p, (e_bdpt.mean(), p)

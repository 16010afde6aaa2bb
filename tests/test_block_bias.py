"""The block bias test (mcvar.experiments.analysis.block_bias_test): power against a
spatially structured bias that the image mean's test cannot see, and its level."""
import numpy as np
import pytest
from scipy import ndimage, stats
from scipy.spatial import ConvexHull

from mcvar.experiments.analysis import block_bias_test

RES, R, CHUNKS, BLOCK = 32, 10, 8, 4


def _truth():
    """A smooth image with a bright square: blur moves light out of it into its rim."""
    i, j = np.mgrid[0:RES, 0:RES] / RES
    img = 0.2 + 0.3 * i * j
    img[10:20, 12:22] += 1.0
    return img


def _replicates(mean, sigma, rng, n):
    return mean + sigma * rng.standard_normal((n, *mean.shape))


def _reference(truth, sigma_chunk, rng):
    chunks = _replicates(truth, sigma_chunk, rng, CHUNKS)
    return chunks.mean(axis=0), chunks.var(axis=0, ddof=1) / CHUNKS


def test_blur_is_detected_where_the_image_mean_test_sees_nothing():
    rng = np.random.default_rng(11)
    truth = _truth()
    blurred = ndimage.gaussian_filter(truth, 1.0, mode="reflect")   # keeps the image sum exactly
    assert blurred.sum() == pytest.approx(truth.sum(), rel=1e-12)
    sigma, sigma_ref = 0.2, 0.1
    ref, ref_var = _reference(truth, sigma_ref, rng)
    x = _replicates(blurred, sigma, rng, R)
    # Power, derived: per block the bias d_b of the block mean over its standard error
    # se_b^2 = (sigma^2 / R + sigma_ref^2 / CHUNKS) / 16 gives the noncentrality
    # lambda = sum d_b^2 / se_b^2 of the chi2(B) statistic (normal approximation of t).
    d = ndimage.uniform_filter(blurred - truth, BLOCK)[BLOCK // 2::BLOCK, BLOCK // 2::BLOCK]
    d = (blurred - truth).reshape(RES // BLOCK, BLOCK, RES // BLOCK, BLOCK).mean(axis=(1, 3))
    se2 = (sigma ** 2 / R + sigma_ref ** 2 / CHUNKS) / BLOCK ** 2
    lam, b = float((d ** 2).sum() / se2), d.size
    alpha = 1e-3
    power = stats.ncx2.sf(stats.chi2.isf(alpha / 2, b), b, lam)
    assert power > 1 - 1e-6, (lam, power)   # the blur is large enough to be seen 'for sure'
    result = block_bias_test(x, ref, ref_var, CHUNKS, block=BLOCK)
    assert result.blocks == b and result.pvalue < alpha, result
    # the image mean's Welch test has no power: its bias is 0 (the blur keeps the sum)
    t_r = x.reshape(R, -1).mean(axis=1)
    z = (t_r.mean() - ref.mean()) / np.sqrt(t_r.var(ddof=1) / R + ref_var.sum() / ref.size ** 2)
    assert abs(z) < stats.norm.isf(alpha / 2), z
    # the worst block touches the bright square's rim
    r0, c0 = result.worst
    assert 6 <= r0 <= 20 and 8 <= c0 <= 22


def test_unbiased_replicates_are_rejected_at_the_stated_rate():
    """Normal replicates and reference: each block's Welch t is (approximately) t-distributed,
    so p_chi2 is uniform and the reported p-value (twice the smaller of p_chi2 and the Sidak
    p of the largest |z|) rejects at level a with probability between a/2 and a. Over N
    trials the count is Binomial; its 1e-6 quantiles bound the observed count."""
    rng = np.random.default_rng(5)
    truth = _truth()
    n, a = 400, 0.1
    p, p_chi2 = np.empty(n), np.empty(n)
    sigma = rng.uniform(0.05, 0.5, truth.shape)       # heteroscedastic pixels
    for k in range(n):
        chunks = truth + sigma * rng.standard_normal((CHUNKS, *truth.shape))
        x = truth + sigma * rng.standard_normal((R, *truth.shape))
        res = block_bias_test(x, chunks.mean(axis=0), chunks.var(axis=0, ddof=1) / CHUNKS, CHUNKS,
                              block=BLOCK)
        p[k], p_chi2[k] = res.pvalue, res.pvalue_chi2
    lo, hi = stats.binom.ppf(1e-6, n, a / 2), stats.binom.isf(1e-6, n, a)
    assert lo <= (p < a).sum() <= hi, (p < a).sum()
    lo, hi = stats.binom.ppf(1e-6, n, a), stats.binom.isf(1e-6, n, a)
    assert lo <= (p_chi2 < a).sum() <= hi, (p_chi2 < a).sum()
    # and the p-values of the chi2 statistic are uniform (Kolmogorov-Smirnov at 1e-6)
    assert stats.kstest(p_chi2, "uniform").pvalue > 1e-6


def test_mask_channels_and_exact_reference():
    rng = np.random.default_rng(2)
    truth = np.stack([_truth()] * 3, axis=-1)
    x = _replicates(truth, 0.1, rng, 5)
    x[:, :4, :4] += 100.0                            # a biased corner, masked out
    mask = np.ones((RES, RES), bool)
    mask[:4, :4] = False
    res = block_bias_test(x, truth, np.zeros_like(truth), 0, block=8, mask=mask)
    assert res.blocks == 16 and res.pvalue > 1e-3
    unmasked = block_bias_test(x, truth, np.zeros_like(truth), 0, block=8)
    assert unmasked.pvalue < 1e-6 and unmasked.worst == (0, 0)
    # a whole block masked out is dropped; edge blocks may be smaller
    mask[:8, :8] = False
    assert block_bias_test(x, truth, np.zeros_like(truth), 0, block=8, mask=mask).blocks == 15
    assert block_bias_test(x[:, :30, :30], truth[:30, :30], np.zeros((30, 30, 3)), 0, block=8).blocks == 16


def test_bad_input_is_named():
    x = np.zeros((4, 8, 8))
    ref, var = np.zeros((8, 8)), np.zeros((8, 8))
    with pytest.raises(ValueError, match="values must have shape"):
        block_bias_test(np.zeros((4, 8, 7)), ref, var, 8)
    with pytest.raises(ValueError, match="ref_variance must have"):
        block_bias_test(x, ref, np.zeros((8, 7)), 8)
    with pytest.raises(ValueError, match=">= 3 replicates"):
        block_bias_test(x[:2], ref, var, 8)
    with pytest.raises(ValueError, match="block must be a positive integer"):
        block_bias_test(x, ref, var, 8, block=0)
    with pytest.raises(ValueError, match="ref_chunks must be"):
        block_bias_test(x, ref, var, -1)
    with pytest.raises(ValueError, match="mask must have shape"):
        block_bias_test(x, ref, var, 8, mask=np.ones((4, 4), bool))
    with pytest.raises(ValueError, match="mask must keep at least one pixel"):
        block_bias_test(x, ref, var, 8, mask=np.zeros((8, 8), bool))


def test_emitter_pixels_are_the_lights_projection():
    """The flagged pixels of the Cornell box at 16 x 16: every pixel whose centre lies in the
    light's projected outline (the camera's pinhole projection of its vertices), and none
    outside the outline's bounding pixels."""
    from mcvar.experiments.chart import emitter_pixels
    from mcvar.scene import cornell_scene

    res = 16
    flagged = emitter_pixels("cornell", res)
    sc = cornell_scene()
    cam = sc.camera
    forward, right, up = cam.basis()
    t = np.tan(np.radians(cam.fov_deg) / 2)
    lights = np.flatnonzero(sc.prim_emission.max(axis=1) > 0)
    verts = np.asarray(sc.triangles)[lights].reshape(-1, 3) - cam.position
    f = verts @ forward
    sx, sy = (verts @ right) / f, (verts @ up) / f
    col = (sx + t) * res / (2 * t)
    row = (t - sy) * res / (2 * t)
    pts = np.column_stack([row, col])
    hull = pts[ConvexHull(pts).vertices]
    from matplotlib.path import Path

    ii, jj = np.mgrid[0:res, 0:res]
    centres = np.column_stack([ii.ravel() + 0.5, jj.ravel() + 0.5])
    inside = Path(hull).contains_points(centres).reshape(res, res)
    assert inside.any() and flagged[inside].all()
    rows, cols = np.nonzero(flagged)
    assert rows.min() >= np.floor(row.min()) and rows.max() <= np.floor(row.max())
    assert cols.min() >= np.floor(col.min()) and cols.max() <= np.floor(col.max())

"""``rr_depth``: Russian roulette starting later is the same estimator in
expectation (bias test against the default, 5 standard errors) and takes a
clear error for bad input."""
import numpy as np
import pytest

from mcvar.integrators import RR_START_DEPTH, render
from mcvar.scene import load_scene

SEED = 77


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


@pytest.mark.parametrize("depth", [1, 8])
def test_later_or_earlier_roulette_is_unbiased(cornell, depth):
    """Per channel, image mean and the top quarter (the ceiling, lit only
    indirectly: most sensitive to roulette) against the default start
    (random sampler: per-pixel variances give the standard errors)."""
    assert depth != RR_START_DEPTH
    res, spp = 16, 64
    a = [render(cornell, spp=spp, res=res, rng=SEED + k, rr_depth=depth) for k in range(2)]
    b = [render(cornell, spp=spp, res=res, rng=SEED + 10 + k) for k in range(2)]
    for rows in (slice(0, res), slice(0, res // 4)):
        for c in range(3):
            def stat(rs):
                k = rs[0].image[rows, :, c].size
                m = np.mean([r.image[rows, :, c].mean() for r in rs])
                v = np.sum([(r.variance[rows, :, c] / r.spp).sum() for r in rs]) / (k * len(rs)) ** 2
                return m, v
            (ma, va), (mb, vb) = stat(a), stat(b)
            assert abs(ma - mb) < 5 * np.sqrt(va + vb), (depth, rows, c, ma, mb)


def test_bad_rr_depth(cornell):
    with pytest.raises(ValueError, match="rr_depth"):
        render(cornell, spp=1, res=4, rr_depth=0)

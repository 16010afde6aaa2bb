"""The general wavefront loop (issue 27): its rewrite without the per-bounce
material sort, with Lambertian materials written out and the other BSDFs
called unchecked on their rows, traces the same paths as the loop it
replaced.

``tests/data/general_loop_f9ebaa9.npz`` holds the per-path radiance of the
old loop (commit f9ebaa9, float64 geometry) for sample vectors as wide as
the paths (so no number comes from ``rng``: each path is a pure function of
its row of ``u``). The same rows must give the same radiance to rounding and
the same number of rays: an identity between two implementations of one
estimator, stronger than any statistical test of the two.
"""
from pathlib import Path

import numpy as np
import pytest

from mcvar.integrators import stream_dim, trace_camera_paths
from mcvar.scene import load_scene
from mcvar.tracer import Tracer

GOLDEN = Path(__file__).parent / "data" / "general_loop_f9ebaa9.npz"
N, DEPTH, RES = 1500, 6, (16, 16)
SCENES = ("cornell-spheres", "cornell-point", "quad-environment", "furnace")


def _inputs(s):
    # the generator of tests/data's fixture: the same seeds, the same draws
    rng = np.random.default_rng(2027 + s)
    pixel = rng.integers(0, RES[0] * RES[1], N)
    return pixel, rng.random((N, stream_dim(DEPTH)))


@pytest.mark.parametrize("method", ["path", "direct_light"])
@pytest.mark.parametrize("s,name", list(enumerate(SCENES)))
def test_general_loop_traces_the_paths_of_the_sorted_loop(s, name, method):
    scene = load_scene(name)
    pixel, u = _inputs(s)
    rad, rays = trace_camera_paths(scene, RES, pixel, u, max_depth=DEPTH if method == "path" else None,
                                   method=method, rng=0, tracer=Tracer(scene, dtype="float64"), kernel="general")
    with np.load(GOLDEN) as g:
        ref, ref_rays = g[f"{name}/{method}/radiance"], int(g[f"{name}/{method}/rays"])
    assert ref.any()                       # the fixture sees light (path_bsdf at a point light would not)
    assert rays == ref_rays
    np.testing.assert_allclose(rad, ref, rtol=1e-12, atol=1e-15)


def _means(r, rows=slice(None)):
    """Per-channel image mean over ``rows`` and its standard error (random sampler: iid samples)."""
    img, var = r.image[rows], r.variance[rows]
    n = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1)) / r.spp) / n


@pytest.mark.parametrize("name,depth,rows", [("cornell-spheres", None, slice(None)),
                                             # the point light's ceiling spot (irradiance I / 1^2) makes the
                                             # full image heavy-tailed: direct light on the lower half instead
                                             ("cornell-point", 2, slice(16, 32))])
def test_float32_path_state_agrees_with_float64(name, depth, rows):
    # The general loop keeps its path state in the tracer's precision (float32
    # by default; sphere intersections stay float64): the image must agree
    # with the float64 loop's in expectation. Independent seeds, random
    # sampler; per channel within 5 combined standard errors, Sidak-corrected
    # over the 3 channels.
    from scipy.stats import norm

    from mcvar.integrators import render
    from mcvar.testing import sidak_significance

    scene = load_scene(name)
    kw = dict(spp=64, res=32, sampler="random", kernel="general", max_depth=depth)
    a = render(scene, rng=11, precision="float64", **kw)
    b = render(scene, rng=12, precision="float32", **kw)
    (ma, sa), (mb, sb) = _means(a, rows), _means(b, rows)
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 3))
    assert np.all(np.abs(ma - mb) < z * np.hypot(sa, sb)), (ma, mb, sa, sb)
    assert ma.min() > 10 * sa.max()        # the comparison sees light, not noise

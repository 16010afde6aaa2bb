"""The lab's toy renderer (mcvar.lab_renderer): its exact image, its correct
method unbiased, each planted bug biased by the amount its closed form says."""
import math

import numpy as np
import pytest
from scipy import stats

from mcvar import lab_renderer as lab
from mcvar.experiments import load_target

R, SPP = 16, 16


def _replicate_means(method, seed):
    streams = np.random.default_rng(seed).spawn(R)
    return np.array([lab.evaluate(method, "random", SPP, g).mean() for g in streams])


def test_exact_image_solves_the_furnace():
    np.testing.assert_allclose(lab.EXACT, lab.EMISSION + lab.ALBEDO * lab.EXACT, rtol=1e-14)
    assert lab.EXACT.shape == (8, 8, 3) and 2 * lab.ALBEDO.max() < 1.0   # even no_cosine has a finite mean


@pytest.mark.parametrize("method, expected", [
    ("path", lab.EXACT),
    ("no_cosine", lab.EMISSION / (1 - 2 * lab.ALBEDO)),          # each bounce keeps 2 rho
    ("pdf_constant", lab.EMISSION / (1 - lab.ALBEDO / 2)),       # each bounce keeps rho / 2
])
def test_each_method_converges_to_its_closed_form(method, expected):
    v = _replicate_means(method, 20261101)
    z = (v.mean() - expected.mean()) / (v.std(ddof=1) / math.sqrt(R))
    assert abs(z) < stats.t.isf(1e-3 / 2, R - 1), (method, v.mean(), expected.mean())


def test_roulette_without_division_is_too_dark():
    v = _replicate_means("roulette_no_division", 20261102)
    t = (v.mean() - lab.EXACT.mean()) / (v.std(ddof=1) / math.sqrt(R))
    assert t < -stats.t.isf(1e-3, R - 1)


def test_furnace_render_with_cosine_bounces_is_unbiased():
    cos = lambda u: (np.sqrt(u), np.sqrt(u) / math.pi)
    streams = np.random.default_rng(20261103).spawn(R)
    v = np.array([lab.furnace_render(cos, SPP, g).mean() for g in streams])
    z = (v.mean() - lab.EXACT.mean()) / (v.std(ddof=1) / math.sqrt(R))
    assert abs(z) < stats.t.isf(1e-3 / 2, R - 1)


def test_the_lab_renderer_is_a_converge_target():
    t = load_target("mcvar.lab_renderer:evaluate")
    assert t.methods == lab.METHODS and t.spp == lab.SPP
    np.testing.assert_array_equal(t.exact, lab.EXACT)


@pytest.mark.parametrize("call, match", [
    (lambda: lab.evaluate("nope", "random", 1, 0), "method"),
    (lambda: lab.evaluate("path", "sobol", 1, 0), "sampler"),
    (lambda: lab.evaluate("path", "random", 0, 0), "spp"),
    (lambda: lab.furnace_render(None, 4), "sample_bounce"),
    (lambda: lab.furnace_render(lambda u: (u, -np.ones_like(u)), 4), "pdf > 0"),
])
def test_bad_arguments(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()

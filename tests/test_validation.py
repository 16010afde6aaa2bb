import numpy as np
import pytest

from mcvar._validation import (as_directions, as_points, as_rgb, as_rng, as_unit_square, check_choice,
                               check_count, check_positive, check_probability)


def test_as_rng_is_deterministic_for_int_seed_and_passes_generators_through():
    a, b = as_rng(123456789), as_rng(123456789)
    assert a.random() == b.random()
    g = np.random.default_rng(5)
    assert as_rng(g) is g
    assert isinstance(as_rng(np.random.SeedSequence(3)), np.random.Generator)


@pytest.mark.parametrize("bad", [1.5, "seed", True, [1]])
def test_as_rng_rejects_other_kinds(bad):
    with pytest.raises(TypeError, match="rng"):
        as_rng(bad)


# ------------------------------------------------ one rule for directions (issue 15)

def _direction_family():
    """Every public function that evaluates something at directions:
    (id, call(d) with d of shape (1, 3), the argument's name)."""
    from mcvar import bsdf as B
    from mcvar import envmap as E
    from mcvar import optics as O
    from mcvar import testing as T
    from mcvar import warps as W

    up = np.array([[0.0, 1.0, 0.0]])
    u = np.full((1, 2), 0.5)
    fam = []
    for name, par in [("uniform_hemisphere", ()), ("cosine_hemisphere", ()), ("uniform_sphere", ()),
                      ("uniform_sphere_flip", ()), ("uniform_cone", (0.5,)), ("phong_lobe", (5.0,)),
                      ("beckmann", (0.3,)), ("ggx", (0.3,))]:
        pdf = getattr(W, f"square_to_{name}_pdf")
        inv = getattr(W, f"{name}_to_square")
        fam += [(f"{name}_pdf", lambda d, f=pdf, p=par: f(d, *p), "v"),
                (f"{name}_to_square", lambda d, f=inv, p=par: f(d, *p), "v")]
    fam += [("ggx_visible.wo", lambda d: W.square_to_ggx_visible(u, d, 0.3), "wo"),
            ("ggx_visible_pdf.h", lambda d: W.square_to_ggx_visible_pdf(d, up, 0.3), "h"),
            ("ggx_visible_pdf.wo", lambda d: W.square_to_ggx_visible_pdf(up, d, 0.3), "wo"),
            ("reflect.w", O.reflect, "w"),
            ("reflect.normal", lambda d: O.reflect(up, d), "normal"),
            ("refract.w", lambda d: O.refract(d, 1.0, 1.5), "w")]
    for b in (B.Lambertian(), B.Mirror(), B.Refractive(1.5), B.Glass(1.5), B.Microfacet(0.3),
              B.Conductor.preset("gold", alpha_x=0.2), B.Plastic(0.5, alpha=0.2), B.Retroreflective()):
        k = type(b).__name__
        fam += [(f"{k}.eval.wo", lambda d, b=b: b.eval(d, up), "wo"),
                (f"{k}.eval.wi", lambda d, b=b: b.eval(up, d), "wi"),
                (f"{k}.pdf.wo", lambda d, b=b: b.pdf(d, up), "wo"),
                (f"{k}.pdf.wi", lambda d, b=b: b.pdf(up, d), "wi"),
                (f"{k}.sample.wo", lambda d, b=b: b.sample(d, u), "wo")]
    env = E.constant(1.0)
    fam += [("directional_albedo.wo", lambda d: B.directional_albedo(B.Lambertian(), d, n=16, rng=1), "wo"),
            ("hemisphere_lookup", lambda d: B.hemisphere_lookup(np.ones((4, 4, 3)), d), "directions"),
            ("envmap.radiance", env.radiance, "directions"),
            ("envmap.pdf", env.pdf, "directions"),
            ("envmap.direction_to_pixel", env.direction_to_pixel, "directions"),
            ("bsdf_chi2_test.wo", lambda d: T.bsdf_chi2_test(B.Lambertian(), d[0], n=64, rng=1), "wo"),
            ("check_weight_consistency.wo",
             lambda d: T.check_weight_consistency(B.Lambertian(), d[0], n=16, rng=1), "wo")]
    return fam


DIRECTION_FAMILY = _direction_family()


@pytest.mark.parametrize("call,name", [f[1:] for f in DIRECTION_FAMILY], ids=[f[0] for f in DIRECTION_FAMILY])
def test_every_direction_taking_function_requires_unit_vectors(call, name):
    """Length 2, 1.001 and 0 are refused naming the argument; a length within
    UNIT_TOLERANCE is accepted and gives the unit vector's result (to rounding)."""
    from mcvar._validation import UNIT_TOLERANCE

    d = np.array([[0.6, 0.8, 0.0]])
    for bad in (2.0 * d, 1.001 * d, 0.0 * d):
        with pytest.raises(ValueError, match=rf"{name} must hold unit vectors .* has length"):
            call(bad)
    ref, near = call(d), call((1.0 + 0.5 * UNIT_TOLERANCE) * d)
    for a, b in zip(ref if isinstance(ref, tuple) else (ref,), near if isinstance(near, tuple) else (near,)):
        if isinstance(a, (np.ndarray, float)):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_the_issue_15_examples():
    """A direction of length 2 used to give 2/pi for the cosine pdf (1/pi at unit length)."""
    from mcvar import warps as W

    with pytest.raises(ValueError, match=r"v must hold unit vectors .* row 0 has length 2.0"):
        W.square_to_cosine_hemisphere_pdf([[0.0, 2.0, 0.0]])
    with pytest.raises(ValueError, match="wo must hold unit vectors"):
        W.square_to_ggx_visible(np.full((1, 2), 0.5), [0, 0, 0], 0.3)


def test_check_count():
    assert check_count(np.int64(7)) == 7
    assert check_count(0, allow_zero=True) == 0
    with pytest.raises(ValueError, match="n must be >= 1; got 0"):
        check_count(0)
    with pytest.raises(ValueError, match="spp must be >= 1"):
        check_count(-3, "spp")
    for bad in (4.0, 2.5, True, "4", None):
        # the issue's contract (ValueError) and the style guide's (TypeError) both hold
        with pytest.raises(ValueError, match="n must be an integer"):
            check_count(bad)
        with pytest.raises(TypeError, match="n must be an integer"):
            check_count(bad)


def test_as_points_checks_shape_range_and_nan():
    pts = as_points([[0.0, 1.0], [0.5, 0.25]], unit=True)
    assert pts.dtype == np.float64 and pts.shape == (2, 2)
    with pytest.raises(ValueError, match=r"points must have shape \(n, 2\)"):
        as_points(np.zeros((4, 3)), d=2)
    with pytest.raises(ValueError, match="points must have 2 dimensions"):
        as_points(np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        as_points([[np.nan, 0.5]])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        as_points([[1.5, 0.5]], unit=True)
    with pytest.raises(ValueError, match="u must"):
        as_unit_square([[-0.1, 0.5]])


def test_scalar_checks():
    assert check_positive(2, "alpha") == 2.0
    with pytest.raises(ValueError, match="alpha must be finite and > 0"):
        check_positive(float("nan"), "alpha")
    with pytest.raises(ValueError, match="eta"):
        check_positive(0.0, "eta")
    assert check_probability(1, "p") == 1.0
    with pytest.raises(ValueError, match="p must lie in"):
        check_probability(1.01, "p")
    assert check_choice("power", "heuristic", ["power", "balance"]) == "power"
    with pytest.raises(ValueError, match="heuristic must be one of"):
        check_choice("max", "heuristic", ["power", "balance"])
    with pytest.raises(ValueError, match=r"wi must have shape \(\.\.\., 3\)"):
        as_directions(np.zeros((3, 2)), "wi")


def test_as_rgb_one_helper_for_bsdf_envmap_and_scene():
    assert as_rgb(0.25, "albedo").tolist() == [0.25, 0.25, 0.25]
    given = np.array([0.1, 0.2, 0.3])
    out = as_rgb(given, "albedo", upper=1.0)
    assert out.tolist() == given.tolist() and out.dtype == np.float64 and out is not given
    assert as_rgb([5.0, 0.0, 2.0], "radiance").tolist() == [5.0, 0.0, 2.0]   # no upper bound
    with pytest.raises(TypeError, match="albedo must be a number or 3 numbers"):
        as_rgb(True, "albedo")
    with pytest.raises(ValueError, match=r"albedo must be a scalar or an RGB triple, shape \(3,\); got shape \(2,\)"):
        as_rgb([0.1, 0.2], "albedo")
    with pytest.raises(ValueError, match=r"albedo must be >= 0 in every channel \(non-negative\)"):
        as_rgb([0.1, -0.1, 0.2], "albedo")
    with pytest.raises(ValueError, match="albedo must be finite"):
        as_rgb([0.1, np.nan, 0.2], "albedo")
    with pytest.raises(ValueError, match=r"albedo must be <= 1.0 in every channel \(energy conservation\)"):
        as_rgb(1.2, "albedo", upper=1.0, why="energy conservation")

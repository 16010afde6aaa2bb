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


def test_check_count():
    assert check_count(np.int64(7)) == 7
    assert check_count(0, allow_zero=True) == 0
    with pytest.raises(ValueError, match="n must be >= 1; got 0"):
        check_count(0)
    with pytest.raises(ValueError, match="spp must be >= 1"):
        check_count(-3, "spp")
    for bad in (4.0, 2.5, True, "4", None):
        # the contract (ValueError) and the style guide's (TypeError) both hold
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

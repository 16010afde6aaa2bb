import numpy as np
import pytest

from mcvar.geometry import (Frame, direction_to_spherical, dot, normalize, spherical_to_direction)


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_frame_is_orthonormal_and_right_handed_everywhere_including_poles():
    rng = np.random.default_rng(20261122)
    n = np.concatenate([_unit(rng, 10000), [[0, 1, 0], [0, -1, 0], [0, -0.0, 1],
                                             [1e-9, -1, 0], [0, -1, 1e-8], [1e-12, 1, 0]]])
    f = Frame(n)
    eps = 8 * np.finfo(float).eps
    for a in (f.s, f.n, f.t):
        np.testing.assert_allclose(dot(a, a), 1.0, atol=eps)
    np.testing.assert_allclose(dot(f.s, f.n), 0.0, atol=eps)
    np.testing.assert_allclose(dot(f.t, f.n), 0.0, atol=eps)
    np.testing.assert_allclose(dot(f.s, f.t), 0.0, atol=eps)
    np.testing.assert_allclose(np.cross(f.s, f.n), f.t, atol=eps)
    assert np.all(np.isfinite(f.s)) and np.all(np.isfinite(f.t))


def test_frame_round_trip_and_normal_maps_to_plus_y():
    rng = np.random.default_rng(7)
    n, v = _unit(rng, 500), _unit(rng, 500)
    f = Frame(n)
    np.testing.assert_allclose(f.to_world(f.to_local(v)), v, atol=1e-14)
    np.testing.assert_allclose(f.to_local(n), np.tile([0.0, 1.0, 0.0], (500, 1)), atol=1e-14)


def test_identity_frame_for_plus_y():
    f = Frame([0.0, 1.0, 0.0])
    v = np.array([0.3, 0.4, 0.5])
    np.testing.assert_allclose(f.to_local(v), v, atol=1e-15)


def test_spherical_round_trip_and_convention():
    np.testing.assert_allclose(spherical_to_direction(0.0, 1.0), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(spherical_to_direction(np.pi / 2, 0.0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(spherical_to_direction(np.pi / 2, np.pi / 2), [0, 0, 1], atol=1e-15)
    rng = np.random.default_rng(3)
    v = _unit(rng, 1000)
    theta, phi = direction_to_spherical(v)
    assert np.all((theta >= 0) & (theta <= np.pi)) and np.all((phi >= 0) & (phi < 2 * np.pi))
    np.testing.assert_allclose(spherical_to_direction(theta, phi), v, atol=1e-14)


def test_zero_vectors_are_rejected():
    with pytest.raises(ValueError, match="zero-length"):
        normalize([[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="zero-length"):
        Frame([0.0, 0.0, 0.0])

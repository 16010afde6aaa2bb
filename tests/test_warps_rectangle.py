"""Solid-angle sampling of rectangular lights (Urena, Fajardo and King 2013):
the sampler against its pdf (chi-square), its inverse, its solid angle against
an independent estimate, and the edges of its domain."""
import numpy as np
import pytest

from mcvar import warps as w
from mcvar.testing import check_inverse, chi2_test

# The Cornell box light (CORNELL.md): a 130 x 105 rectangle facing down.
ORIGIN = np.array([343.0, 548.7, 227.0])
E1 = np.array([-130.0, 0.0, 0.0])
E2 = np.array([0.0, 0.0, 105.0])
REFS = {
    "below": np.array([250.0, 400.0, 300.0]),      # large solid angle, off centre
    "floor": np.array([50.0, 0.0, 500.0]),         # the floor's far corner
    "grazing": np.array([100.0, 548.0, 100.0]),    # almost in the light's plane
}


def _square_pair(ref):
    """The sampler as a map of [0, 1]^2 onto the light's own coordinates (s, t)
    in [0, 1]^2, and its density there: ``pdf_w * cos(theta_light) / r^2 * area``
    (solid angle to area, then area to the unit square). The support is the
    whole square, so no histogram cell straddles the light's edge."""
    area = 130.0 * 105.0

    def sample(u):
        p = w.square_to_spherical_rectangle(u, np.broadcast_to(ref, (len(u), 3)), ORIGIN, E1, E2)
        return w.uniform_parallelogram_to_square(p, ORIGIN, E1, E2)

    def pdf(st):
        p = w.square_to_uniform_parallelogram(st, ORIGIN, E1, E2)
        refs = np.broadcast_to(ref, p.shape)
        d = p - refs
        r2 = np.einsum("ij,ij->i", d, d)
        cos_l = np.abs(d[:, 1]) / np.sqrt(r2)
        return w.square_to_spherical_rectangle_pdf(p, refs, ORIGIN, E1, E2) * cos_l / r2 * area

    return sample, pdf


@pytest.mark.parametrize("where", sorted(REFS))
def test_chi2_against_pdf(where):
    sample, pdf = _square_pair(REFS[where])
    res = chi2_test(sample, pdf, "square", n=400_000, rng=7, bins=(40, 40), test_count=len(REFS))
    assert res.passed, res


def test_solid_angle_matches_area_integral():
    """1 / pdf is the solid angle; compare with the area integral of
    cos(theta_light) / r^2 by Monte Carlo (5 standard errors)."""
    rng = np.random.default_rng(3)
    n = 200_000
    for ref in REFS.values():
        u = rng.random((n, 2))
        pts = w.square_to_uniform_parallelogram(u, ORIGIN, E1, E2)
        d = pts - ref
        r2 = np.einsum("ij,ij->i", d, d)
        g = np.abs(d[:, 1]) / r2 ** 1.5 * 130 * 105
        mc, se = g.mean(), g.std(ddof=1) / np.sqrt(n)
        p = w.square_to_spherical_rectangle(u[:1], ref[None], ORIGIN, E1, E2)
        s = 1.0 / w.square_to_spherical_rectangle_pdf(p, ref[None], ORIGIN, E1, E2)[0]
        assert abs(s - mc) < 5 * se, (s, mc, se)


def test_inverse_round_trip():
    ref = REFS["below"]
    fwd = lambda u: w.square_to_spherical_rectangle(u, np.broadcast_to(ref, (len(u), 3)), ORIGIN, E1, E2)
    inv = lambda p: w.spherical_rectangle_to_square(p, np.broadcast_to(ref, (len(p), 3)), ORIGIN, E1, E2)
    res = check_inverse(fwd, inv, n=20_000, rng=5)
    assert res.passed, res


def test_corners_and_edges_of_the_square():
    """u = 0 and u = 1 exactly land on the rectangle's corners; every sample is
    finite and on the rectangle, also from a grazing reference point."""
    u = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    for ref in REFS.values():
        p = w.square_to_spherical_rectangle(u, np.broadcast_to(ref, (4, 3)), ORIGIN, E1, E2)
        corners = {tuple(np.round(c, 6)) for c in ORIGIN + np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) @ np.stack([E1, E2])}
        assert {tuple(np.round(q, 6)) for q in p} <= corners
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 33), np.linspace(0, 1, 33)), -1).reshape(-1, 2)
    ref = np.broadcast_to(REFS["grazing"], (len(grid), 3))
    p = w.square_to_spherical_rectangle(grid, ref, ORIGIN, E1, E2)
    assert np.all(np.isfinite(p))
    assert np.all(w.square_to_uniform_parallelogram_pdf(p, ORIGIN, E1, E2) > 0)


def test_pdf_zero_off_the_light_and_edge_on():
    ref = REFS["below"][None]
    off = np.array([[100.0, 548.7, 100.0]])           # in the plane, outside the rectangle
    assert w.square_to_spherical_rectangle_pdf(off, ref, ORIGIN, E1, E2)[0] == 0.0
    in_plane = np.array([[0.0, 548.7, 0.0]])           # a reference point in the light's plane
    on = ORIGIN[None] + 0.5 * (E1 + E2)
    assert w.square_to_spherical_rectangle_pdf(on, in_plane, ORIGIN, E1, E2)[0] == 0.0


def test_rejects_a_parallelogram():
    with pytest.raises(ValueError, match="orthogonal"):
        w.square_to_spherical_rectangle([[0.5, 0.5]], [[0.0, 0.0, 0.0]], ORIGIN, E1, E1 + E2)

"""Property-based fuzzing of the public functions that take arrays (issue 15).

Every public function that takes arrays is called with inputs a careless or
adversarial user could pass: NaN and +-Inf, empty arrays, wrong shapes and
dtypes (float32, int, bool, complex, strings, ragged lists, None), ``u`` equal
to 0 and 1 exactly, grazing and below-horizon directions, vectors just inside
and just outside the unit-length tolerance, and extreme parameters (eta -> 1,
roughness -> 0, huge exponents, cones of almost zero angle).

The invariant, for every call: either a result whose every number is finite,
or a ``ValueError`` / ``TypeError`` whose message names the argument (one of
the names listed for the case). Anything else (a NaN or Inf in the output,
an ``IndexError``, a ``ZeroDivisionError``, numpy's own broadcasting message)
fails. ``hypothesis`` draws 20 inputs per case (deadline off: the machine is
shared; ``MCVAR_FUZZ_EXAMPLES`` raises the count for a deeper search);
``pytest --hypothesis-show-statistics`` prints how many calls returned and
how many raised.
"""
from __future__ import annotations

import dataclasses
import math
import os
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from mcvar import bsdf as B
from mcvar import discrepancy as D
from mcvar import envmap as E
from mcvar import images as I
from mcvar import optics as O
from mcvar import samplers as S
from mcvar import warps as W
from mcvar._validation import UNIT_TOLERANCE

# 20 inputs per case in CI (derandomized: the same inputs every run); set
# MCVAR_FUZZ_EXAMPLES=500 and MCVAR_FUZZ_SEED=<n> to search deeper on demand.
_EXAMPLES = int(os.environ.get("MCVAR_FUZZ_EXAMPLES", "20"))
FUZZ = settings(max_examples=_EXAMPLES, deadline=None, derandomize="MCVAR_FUZZ_SEED" not in os.environ,
                database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

ONE_MINUS = float(np.nextafter(1.0, 0.0))
NASTY = [np.nan, np.inf, -np.inf, -1e-300, 1.0 + 1e-12, 2.0, -1.0, 1e308, 5e-324]

# ------------------------------------------------------------------ strategies


def _rows(n_max=5):
    return st.integers(0, n_max)


@st.composite
def unit_square(draw, d=2):
    """(n, d) points in [0, 1]^d, rich in 0, 1 and the float just below 1."""
    n = draw(_rows())
    elem = st.one_of(st.sampled_from([0.0, 1.0, ONE_MINUS, 0.5, 5e-324, 1e-300]),
                     st.floats(0.0, 1.0))
    return np.array(draw(st.lists(st.lists(elem, min_size=d, max_size=d), min_size=n, max_size=n)),
                    dtype=np.float64).reshape(n, d)


@st.composite
def unit_directions(draw):
    """(n, 3) unit vectors: poles, the horizon (y = 0 exactly), below it, and
    lengths just inside the unit tolerance."""
    n = draw(_rows())
    rows = []
    for _ in range(n):
        kind = draw(st.sampled_from(["pole", "horizon", "any", "near_horizon", "jiggle"]))
        if kind == "pole":
            v = np.array([0.0, draw(st.sampled_from([1.0, -1.0])), 0.0])
        elif kind == "horizon":
            phi = draw(st.floats(0.0, 2 * math.pi))
            v = np.array([math.cos(phi), 0.0, math.sin(phi)])
        else:
            if kind == "near_horizon":
                cos_t = draw(st.sampled_from([1e-300, -1e-300, 1e-12, -1e-12, 5e-324]))
            else:
                cos_t = draw(st.floats(-1.0, 1.0))
            phi = draw(st.floats(0.0, 2 * math.pi))
            s = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
            v = np.array([s * math.cos(phi), cos_t, s * math.sin(phi)])
            if kind == "jiggle":
                v = v * (1.0 + draw(st.sampled_from([-0.5, 0.5])) * UNIT_TOLERANCE)
        rows.append(v)
    return np.array(rows, dtype=np.float64).reshape(n, 3)


@st.composite
def plane_points(draw, d=2, lo=-1.5, hi=1.5):
    n = draw(_rows())
    elem = st.one_of(st.sampled_from([0.0, 1.0, -1.0, 0.5]), st.floats(lo, hi))
    return np.array(draw(st.lists(st.lists(elem, min_size=d, max_size=d), min_size=n, max_size=n)),
                    dtype=np.float64).reshape(n, d)


def _spoil(arr: np.ndarray, draw):
    """One entry replaced by a nasty value (NaN, Inf, out of range)."""
    if arr.size == 0:
        return arr
    out = arr.copy()
    out.flat[draw(st.integers(0, arr.size - 1))] = draw(st.sampled_from(NASTY))
    return out


@st.composite
def fuzzed(draw, good):
    """A valid array from ``good`` most of the time, else a broken variant."""
    arr = draw(good)
    how = draw(st.sampled_from(["good", "good", "good", "spoil", "float32", "int", "bool", "complex",
                                "str", "list", "ragged", "shape", "scalar", "none", "empty"]))
    event(f"input: {how}")
    if how == "good":
        return arr
    if how == "spoil":
        return _spoil(arr, draw)
    if how == "float32":
        return arr.astype(np.float32)
    if how == "int":
        return arr.astype(np.int64)
    if how == "bool":
        return arr.astype(bool)
    if how == "complex":
        return arr.astype(np.complex128) + 1j
    if how == "str":
        return arr.astype(str)
    if how == "list":
        return arr.tolist()
    if how == "ragged":
        return [[0.5, 0.5], [0.5]]
    if how == "shape":
        shape = draw(st.sampled_from([(), (3,), (2, 1), (2, 4), (1, 2, 3), (0,), (2, 2, 2)]))
        return np.full(shape, 0.5)
    if how == "scalar":
        return draw(st.sampled_from([0.5, np.nan, "abc", 3]))
    if how == "none":
        return None
    return np.empty((0,) + arr.shape[1:])


# ------------------------------------------------------------------ the invariant

def _finite(x) -> bool:
    if isinstance(x, (tuple, list)):
        return all(_finite(y) for y in x)
    if isinstance(x, np.ndarray) and x.dtype.kind in "biu":
        return True
    if isinstance(x, (bool, np.bool_, int, np.integer, str)):
        return True
    if hasattr(x, "__dataclass_fields__"):
        return all(_finite(getattr(x, f)) for f in x.__dataclass_fields__)
    arr = np.asarray(x)
    if arr.dtype.kind not in "fc":
        return True
    return bool(np.all(np.isfinite(arr)))


def _holds(label, call, value, names):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sobol's power-of-2 warning, numpy's ComplexWarning
        try:
            out = call(value)
        except (ValueError, TypeError) as exc:
            msg = str(exc)
            assert any(n in msg for n in names), f"{label}: message does not name {names}: {msg!r}"
            event("outcome: named error")
            return
    assert _finite(out), f"{label}: non-finite result for input {value!r}: {out!r}"
    event("outcome: finite result")


# ------------------------------------------------------------------ the cases

ALPHAS = [W.ALPHA_MIN, 1e-8, 0.3, 1.0]
WARP_FAMILIES = [  # (name, sampler, pdf, inverse, parameter tuples)
    ("uniform_hemisphere", W.square_to_uniform_hemisphere, W.square_to_uniform_hemisphere_pdf,
     W.uniform_hemisphere_to_square, [()]),
    ("cosine_hemisphere", W.square_to_cosine_hemisphere, W.square_to_cosine_hemisphere_pdf,
     W.cosine_hemisphere_to_square, [()]),
    ("uniform_sphere", W.square_to_uniform_sphere, W.square_to_uniform_sphere_pdf,
     W.uniform_sphere_to_square, [()]),
    ("uniform_sphere_flip", W.square_to_uniform_sphere_flip, W.square_to_uniform_sphere_flip_pdf,
     W.uniform_sphere_flip_to_square, [()]),
    ("uniform_cone", W.square_to_uniform_cone, W.square_to_uniform_cone_pdf, W.uniform_cone_to_square,
     [(ONE_MINUS,), (0.0,), (-1.0,)]),
    ("phong_lobe", W.square_to_phong_lobe, W.square_to_phong_lobe_pdf, W.phong_lobe_to_square,
     [(0.0,), (1e6,)]),
    ("beckmann", W.square_to_beckmann, W.square_to_beckmann_pdf, W.beckmann_to_square,
     [(a,) for a in ALPHAS]),
    ("ggx", W.square_to_ggx, W.square_to_ggx_pdf, W.ggx_to_square,
     [(a,) for a in ALPHAS] + [(W.ALPHA_MIN, 1.0)]),
]

CASES = []  # (id, call(value), names, strategy)
for fam, sample, pdf, inverse, params in WARP_FAMILIES:
    for k, par in enumerate(params):
        CASES += [
            (f"{fam}[{k}].sample", (lambda x, f=sample, p=par: f(x, *p)), ("u",), fuzzed(unit_square())),
            (f"{fam}[{k}].pdf", (lambda x, f=pdf, p=par: f(x, *p)), ("v",), fuzzed(unit_directions())),
            (f"{fam}[{k}].inverse", (lambda x, f=inverse, p=par: f(x, *p)), ("v",), fuzzed(unit_directions())),
        ]
for a in (W.ALPHA_MIN, 0.3):
    WO = np.array([0.6, 0.0, 0.8])  # grazing
    CASES += [
        (f"ggx_visible[{a}].u", lambda x, a=a: W.square_to_ggx_visible(x, [0.0, 1.0, 0.0], a), ("u",),
         fuzzed(unit_square())),
        (f"ggx_visible[{a}].wo", lambda x, a=a: W.square_to_ggx_visible(np.full((1, 2), 0.5), x, a),
         ("wo", "u"), fuzzed(unit_directions())),
        (f"ggx_visible_pdf[{a}].h", lambda x, a=a: W.square_to_ggx_visible_pdf(x, WO, a), ("h",),
         fuzzed(unit_directions())),
        (f"ggx_visible_pdf[{a}].wo", lambda x, a=a: W.square_to_ggx_visible_pdf(np.array([[0.0, 1.0, 0.0]]), x, a),
         ("wo", "h"), fuzzed(unit_directions())),
    ]
CASES += [
    ("disk.sample", W.square_to_uniform_disk_concentric, ("u",), fuzzed(unit_square())),
    ("disk.pdf", W.square_to_uniform_disk_concentric_pdf, ("p",), fuzzed(plane_points())),
    ("disk.inverse", W.uniform_disk_concentric_to_square, ("p",), fuzzed(plane_points())),
    ("triangle.sample", W.square_to_uniform_triangle, ("u",), fuzzed(unit_square())),
    ("triangle.pdf", W.square_to_uniform_triangle_pdf, ("b",), fuzzed(plane_points())),
    ("triangle.inverse", W.uniform_triangle_to_square, ("b",), fuzzed(plane_points())),
    ("world_triangle.pdf", lambda x: W.square_to_world_triangle_pdf(x, [0, 0, 0], [1, 0, 0], [0, 0, 1]),
     ("points",), fuzzed(plane_points(3))),
    ("world_triangle.inverse", lambda x: W.world_triangle_to_square(x, [0, 0, 0], [1, 0, 0], [0, 0, 1]),
     ("points",), fuzzed(plane_points(3))),
    ("parallelogram.pdf", lambda x: W.square_to_uniform_parallelogram_pdf(x, [0, 0, 0], [1, 0, 0], [0, 0, 1]),
     ("points",), fuzzed(plane_points(3))),
    ("parallelogram.inverse", lambda x: W.uniform_parallelogram_to_square(x, [0, 0, 0], [1, 0, 0], [0, 0, 1]),
     ("points",), fuzzed(plane_points(3))),
    ("area_to_solid_angle.light_points",
     lambda x: W.area_to_solid_angle_pdf(1.0, [0.0, 0.0, 0.0], x, [0.0, -1.0, 0.0]),
     ("light_points", "pdf_area"), fuzzed(plane_points(3))),
]

# optics: directions, cosines and extreme indices of refraction
ETAS = [(1.0, 1.0), (1.0, 1.0 + 1e-12), (1.5, 1.0), (1.0, 1e6)]
for k, (ei, et) in enumerate(ETAS):
    CASES += [
        (f"refract[{k}]", lambda x, ei=ei, et=et: O.refract(x, ei, et), ("w",), fuzzed(unit_directions())),
        (f"fresnel_dielectric[{k}]", lambda x, ei=ei, et=et: O.fresnel_dielectric(x, ei, et), ("cos_i",),
         fuzzed(plane_points(1, -1.0, 1.0))),
        (f"fresnel_schlick[{k}]", lambda x, ei=ei, et=et: O.fresnel_schlick(x, ei, et), ("cos_i",),
         fuzzed(plane_points(1, -1.0, 1.0))),
    ]
CASES += [
    ("reflect.w", O.reflect, ("w",), fuzzed(unit_directions())),
    ("reflect.normal", lambda x: O.reflect(np.array([[0.0, 1.0, 0.0]]), x), ("normal", "w"),
     fuzzed(unit_directions())),
    ("fresnel_conductor", lambda x: O.fresnel_conductor(x, B.COPPER["eta"], B.COPPER["k"]), ("cos_i",),
     fuzzed(plane_points(1, -1.0, 1.0))),
]

# BSDFs at extreme parameters: eta -> 1, roughness -> 0, huge exponents
BSDFS = {
    "lambertian": B.Lambertian(0.8),
    "mirror": B.Mirror(),
    "refractive_eta1": B.Refractive(1.0 + 1e-12),
    "glass_eta1": B.Glass(1.0 + 1e-12),
    "glass_schlick": B.Glass(1.5, fresnel="schlick"),
    "microfacet_smooth": B.Microfacet(1e-8),
    "microfacet_beckmann": B.Microfacet(1e-8, distribution="beckmann"),
    "microfacet_aniso": B.Microfacet(1.0, 1e-6),
    "conductor_smooth": B.Conductor.preset("gold"),
    "conductor_rough": B.Conductor.preset("copper", alpha_x=1e-8),
    "plastic_smooth": B.Plastic(0.5, eta=1.0 + 1e-12),
    "plastic_rough": B.Plastic(0.5, alpha=1e-8),
    "retro": B.Retroreflective(0.8, exponent=1e6),
}
UP = np.array([[0.0, 1.0, 0.0]])
for name, bsdf in BSDFS.items():
    CASES += [
        (f"{name}.eval.wo", lambda x, b=bsdf: b.eval(x, np.broadcast_to(UP, np.shape(x)) if _n3(x) else UP),
         ("wo", "wi"), fuzzed(unit_directions())),
        (f"{name}.eval.wi", lambda x, b=bsdf: b.eval(np.broadcast_to(UP, np.shape(x)) if _n3(x) else UP, x),
         ("wi", "wo"), fuzzed(unit_directions())),
        (f"{name}.pdf.wi", lambda x, b=bsdf: b.pdf(np.broadcast_to(UP, np.shape(x)) if _n3(x) else UP, x),
         ("wi", "wo"), fuzzed(unit_directions())),
        (f"{name}.sample.wo", lambda x, b=bsdf: b.sample(x, np.full((len(x) if _n3(x) else 1, 2), ONE_MINUS)),
         ("wo", "u"), fuzzed(unit_directions())),
        (f"{name}.sample.u", lambda x, b=bsdf: b.sample(np.broadcast_to(UP, (np.shape(x)[0], 3))
                                                        if _n2(x) else UP, x),
         ("u", "wo"), fuzzed(unit_square())),
    ]

ENV = E.sky_with_sun(height=16, width=32)
CASES += [
    ("envmap.sample", ENV.sample, ("u",), fuzzed(unit_square())),
    ("envmap.pdf", ENV.pdf, ("directions",), fuzzed(unit_directions())),
    ("envmap.radiance", ENV.radiance, ("directions",), fuzzed(unit_directions())),
    ("envmap.radiance_bilinear", lambda x: ENV.radiance(x, interpolation="bilinear"), ("directions",),
     fuzzed(unit_directions())),
    ("envmap.direction_to_pixel", ENV.direction_to_pixel, ("directions",), fuzzed(unit_directions())),
    ("hemisphere_lookup", lambda x: B.hemisphere_lookup(np.ones((4, 4, 3)), x), ("directions",),
     fuzzed(unit_directions())),
]

# discrepancy (an empty set may be refused, by name) and point-set randomizers
for fname in ("star", "l2_star", "centered", "wrap_around", "mixture", "local", "power_spectrum"):
    CASES.append((f"discrepancy.{fname}", getattr(D, fname), ("points",), fuzzed(unit_square())))
CASES += [
    ("discrepancy.is_net", lambda x: D.is_net(x, 2), ("points",), fuzzed(unit_square())),
    ("cranley_patterson", lambda x: S.cranley_patterson(x, rng=1), ("points",), fuzzed(unit_square(3))),
    ("digital_shift", lambda x: S.digital_shift(x, rng=1), ("points",), fuzzed(unit_square())),
]

# images: linear values and RGB images
CASES += [
    ("linear_to_srgb", I.linear_to_srgb, ("values",), fuzzed(plane_points(3, 0.0, 4.0))),
    ("srgb_to_linear", I.srgb_to_linear, ("values",), fuzzed(plane_points(3, 0.0, 1.0))),
    ("to_srgb8", lambda x: I.to_srgb8(np.asarray(x)[None] if isinstance(x, np.ndarray) else x),
     ("image",), fuzzed(plane_points(3, 0.0, 4.0))),
    ("rgbe_encode", lambda x: I.rgbe_encode(np.asarray(x)[None] if isinstance(x, np.ndarray) else x),
     ("image",), fuzzed(plane_points(3, 0.0, 1e4))),
]


def _n3(x) -> bool:
    return isinstance(x, np.ndarray) and x.ndim == 2 and x.shape[1] == 3


def _n2(x) -> bool:
    return isinstance(x, np.ndarray) and x.ndim == 2 and x.shape[1] == 2


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
@FUZZ
@given(data=st.data())
def test_arrays_give_finite_results_or_named_errors(case, data):
    label, call, names, strategy = case
    _holds(label, call, data.draw(strategy), names)


# ------------------------------------------------------------------ samplers: counts

COUNTS = st.one_of(st.integers(-3, 70), st.sampled_from([0, 1, 2, 2 ** 40, 2 ** 63]),
                   st.sampled_from([4.0, 2.5, np.nan, "16", None, True, np.int64(16), np.uint8(9)]))


@pytest.mark.parametrize("name", list(S.SAMPLERS))
@FUZZ
@given(n=COUNTS)
def test_samplers_give_unit_square_points_or_named_errors(name, n):
    def call(n):
        p = S.get_sampler(name)(n, rng=20_261_201)
        assert p.shape == (int(n), 2) and p.dtype == np.float64, name
        assert np.all((p >= 0.0) & (p < 1.0)), name
        return p
    _holds(name, call, n, ("n",))


@FUZZ
@given(n_pixels=COUNTS, spp=st.sampled_from([0, 1, 4, 16, 15, 2 ** 40]),
       sampler=st.sampled_from(list(S.SAMPLERS)))
def test_pixel_samples_fuzz(n_pixels, spp, sampler):
    if isinstance(n_pixels, (int, np.integer)) and not isinstance(n_pixels, bool) and n_pixels > 64:
        n_pixels = 64 if n_pixels < 2 ** 30 else n_pixels  # keep small sets fast, keep the huge ones
    _holds("pixel_samples", lambda x: S.pixel_samples(sampler, x, spp, dim=3, rng=3),
           n_pixels, ("n_pixels", "spp"))


# ------------------------------------------------------------------ what the fuzzer found
# (a deeper run, MCVAR_FUZZ_EXAMPLES=300 MCVAR_FUZZ_SEED=1, found these; pinned here
# because the 20 derandomized inputs per case above need not hit them again)

@pytest.mark.parametrize("bsdf", [B.Microfacet(1.0, 1e-6), B.Microfacet(0.3, distribution="beckmann"),
                                  B.Plastic(0.5, alpha=1e-8), B.Conductor.preset("copper", alpha_x=0.2)],
                         ids=repr)
@pytest.mark.parametrize("cos_o", [1e-300, 5e-324, 1e-160])
def test_microfacet_wo_at_the_underflowing_horizon_is_finite(bsdf, cos_o):
    """cos_o^2 (or cos_o cos_i) underflowing to 0 made Lambda = inf and the weight
    inf / inf = NaN (GGX sample) or 0 / 0 (eval); now such samples fail cleanly."""
    wo = np.array([[math.sqrt(1.0 - cos_o * cos_o), cos_o, 0.0]])
    u = np.array([[ONE_MINUS, 0.25]])
    s = bsdf.sample(wo, u)
    assert _finite(tuple(s)), s
    wi = np.array([[0.0, cos_o, 1.0]])
    assert np.all(np.isfinite(bsdf.eval(wo, wi))) and np.all(np.isfinite(bsdf.pdf(wo, wi)))


def test_found_by_the_fuzzer_named_errors():
    with pytest.raises(ValueError, match="overflows float64.*light_points"):
        W.area_to_solid_angle_pdf(1.0, [0.0, 0.0, 0.0], [0.0, 1e308, 0.0], [0.0, -1.0, 0.0])
    with pytest.raises(TypeError, match="values must be array-like of real numbers"):
        I.srgb_to_linear([[0.5, 0.5], [0.5]])
    with pytest.raises(TypeError, match="v must be array-like of real numbers; got ndarray with complex"):
        W.square_to_cosine_hemisphere_pdf(np.array([[0.0, 1.0, 0.0]]) + 1j)


# ------------------------------------------------------------------ issue 24: the newer parts
# Method options, hand-built scenes, piecewise domains, metric and grader
# arguments. The same invariant: a result that is valid (finite, in range, and
# for piecewise domains pdf(sample(u)) equal to the returned pdf), or a
# ValueError / TypeError naming the argument.

from mcvar import metrics as MET  # noqa: E402
from mcvar.integrators import METHODS  # noqa: E402
from mcvar.piecewise import PiecewiseConstant1D, PiecewiseConstant2D  # noqa: E402
from mcvar.scene import Scene, load_scene  # noqa: E402
from mcvar.testing import grade as GR  # noqa: E402

#: Values a careless user gives an option: right and wrong types, booleans as
#: strings and numbers, zero, negative, NaN, fractional and far too large counts.
OPTION_VALUES = [True, False, np.True_, np.False_, "no", "yes", "True", 0, 1, -1, 2, 2.5, 1e-3, 70.0,
                 np.nan, np.inf, None, 2 ** 40, 1 << 14, "path", [1]]
OPTION_METHODS = [m for m in METHODS if METHODS[m].options]


@st.composite
def method_options(draw, name):
    method = METHODS[name]
    keys = draw(st.lists(st.sampled_from(sorted(method.options)), min_size=1, max_size=3, unique=True))
    return name, {k: draw(st.one_of(st.just(method.options[k]), st.sampled_from(OPTION_VALUES))) for k in keys}


_CORNELL = {}


def _scene(name):
    if name not in _CORNELL:
        _CORNELL[name] = load_scene(name)
    return _CORNELL[name]


@pytest.mark.parametrize("name", OPTION_METHODS)
@FUZZ
@given(data=st.data())
def test_method_options_are_checked_or_named(name, data):
    """An option set either passes the method's checks (every bool option then
    holds a bool) or is refused naming one of the options, before any ray."""
    _, opts = data.draw(method_options(name))
    method = METHODS[name]
    try:
        resolved = method.resolve_options(opts)
        if method.check_scene is not None:
            method.check_scene(_scene("cornell"), resolved)
    except (ValueError, TypeError) as exc:
        msg = str(exc)
        assert any(k in msg for k in opts) or "scene" in msg or "light" in msg, f"{name} {opts}: {msg!r}"
        event("outcome: named error")
        return
    for k, default in method.options.items():
        if isinstance(default, bool):
            assert isinstance(resolved[k], (bool, np.bool_)), f"{name}: {k}={resolved[k]!r} accepted"
    event("outcome: accepted")


SCENE_FIELDS = ["triangles", "sphere_centers", "sphere_radii", "prim_material", "prim_emission",
                "prim_two_sided_emission", "prim_light", "light_origin", "light_edge1", "light_edge2",
                "light_radiance", "materials", "material_names", "point_light_position", "point_light_intensity"]


@st.composite
def spoiled_scene_field(draw):
    base = _scene("cornell-spheres")
    field = draw(st.sampled_from(SCENE_FIELDS))
    value = getattr(base, field)
    how = draw(st.sampled_from(["nan", "inf", "huge", "negative", "shape", "str", "drop_row", "float", "good"]))
    if field in ("materials", "material_names"):
        value = draw(st.sampled_from([("white",) * len(base.materials), "white", (None,) * len(base.materials),
                                      value[:1], value]))
    elif value is None or np.size(value) == 0:
        value = draw(st.sampled_from([np.full((1, 3), np.nan), np.zeros((2, 2)), None, np.ones((1, 3))]))
    else:
        arr = np.array(value, dtype=np.float64 if how in ("nan", "inf", "huge", "negative", "float") else None)
        if how in ("nan", "inf", "huge", "negative"):
            arr.flat[draw(st.integers(0, arr.size - 1))] = {"nan": np.nan, "inf": np.inf, "huge": 1e300,
                                                            "negative": -1.0}[how]
        elif how == "float":
            arr = arr + 0.5
        elif how == "shape":
            arr = arr.reshape(-1)[: max(1, arr.size - 1)]
        elif how == "str":
            arr = arr.astype(str)
        elif how == "drop_row":
            arr = arr[1:]
        value = arr
    event(f"scene field: {how}")
    return field, value


@FUZZ
@given(case=spoiled_scene_field())
def test_scenes_are_valid_or_refused_naming_the_field(case):
    field, value = case
    base = _scene("cornell-spheres")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = dataclasses.replace(base, **{field: value})
    except (ValueError, TypeError) as exc:
        msg = str(exc)
        assert field in msg or "per primitive" in msg or "light_" in msg, f"{field}: {msg!r}"
        event("outcome: named error")
        return
    n = s.n_triangles + s.n_spheres
    assert s.triangles.shape == (s.n_triangles, 3, 3) and s.prim_emission.shape == (n, 3)
    for f in ("triangles", "sphere_centers", "sphere_radii", "prim_emission", "light_origin", "light_edge1",
              "light_edge2", "light_radiance", "point_light_position", "point_light_intensity"):
        arr = getattr(s, f)
        assert np.all(np.isfinite(arr)), f
    assert np.all(s.prim_emission >= 0) and np.all(s.light_radiance >= 0) and np.all(s.sphere_radii > 0)
    assert np.all(s.light_area > 0) and all(isinstance(m, B.BSDF) for m in s.materials)
    event("outcome: accepted")


DOMAIN_ENDS = [0.0, -1.0, 1.0, 1e-300, -1e308, 1e308, 5e-324, 1e300, -3.0]
DOMAIN_WIDTHS = [1.0, 1e-320, 1e-300, 1e-15, 1e-9, 1e308, 1e200, 3.5, np.inf, 0.0, -1.0, np.nan]


@FUZZ
@given(func=st.lists(st.sampled_from([0.0, 1.0, 2.5, 1e-300, 1e300]), min_size=1, max_size=6),
       lo=st.sampled_from(DOMAIN_ENDS), width=st.sampled_from(DOMAIN_WIDTHS),
       u=st.lists(st.sampled_from([0.0, 1.0, ONE_MINUS, 0.5, 1e-300, 0.3]), min_size=1, max_size=6))
def test_piecewise_1d_domains(func, lo, width, u):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hi = lo + width
    try:
        d = PiecewiseConstant1D(func, lo, hi)
    except (ValueError, TypeError) as exc:
        assert "domain" in str(exc) or "func" in str(exc), str(exc)
        event("outcome: named error")
        return
    x, pdf, k = d.sample(np.array(u))
    assert np.all(np.isfinite(x)) and np.all((x >= d.min) & (x <= d.max))
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    np.testing.assert_array_equal(d.pdf(x), pdf)
    event("outcome: accepted")


@FUZZ
@given(shape=st.tuples(st.integers(1, 4), st.integers(1, 4)),
       lo=st.tuples(st.sampled_from(DOMAIN_ENDS), st.sampled_from(DOMAIN_ENDS)),
       width=st.tuples(st.sampled_from(DOMAIN_WIDTHS), st.sampled_from(DOMAIN_WIDTHS)))
def test_piecewise_2d_domains(shape, lo, width):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        domain = ((lo[0], lo[0] + width[0]), (lo[1], lo[1] + width[1]))
    f = np.arange(1.0, 1.0 + shape[0] * shape[1]).reshape(shape)
    try:
        d = PiecewiseConstant2D(f, domain)
    except (ValueError, TypeError) as exc:
        assert "domain" in str(exc), str(exc)
        event("outcome: named error")
        return
    u = np.array([[0.0, 0.0], [1.0, 1.0], [0.5, ONE_MINUS], [0.3, 0.7]])
    p, pdf, _ = d.sample(u)
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    np.testing.assert_array_equal(d.pdf(p), pdf)
    event("outcome: accepted")


METRIC_VALUES = [None, 1.0, 0.0, -1.0, np.nan, np.inf, "abc", True, 5, -1, 2, 3, 7, 2.5, "last"]


METRIC_ARGS = [("relative_mse", "eps"), ("psnr", "data_range"), ("ssim", "data_range"), ("ssim", "channel_axis"),
               ("ssim", "win_size")]


@pytest.mark.parametrize("fn, key", METRIC_ARGS)
@FUZZ
@given(value=st.sampled_from(METRIC_VALUES), grey=st.booleans())
def test_metric_arguments(fn, key, value, grey):
    if value is None and key == "eps":
        return
    rng = np.random.default_rng(3)
    ref = rng.random((8, 8) if grey else (8, 8, 3))
    est = ref + 0.05
    call = {"relative_mse": MET.relative_mse, "psnr": MET.peak_signal_noise_ratio,
            "ssim": MET.structural_similarity}[fn]
    _holds(f"{fn}({key}={value!r})", lambda v: call(ref, est, **{key: v}), value, (key,))


@FUZZ
@given(exact=st.one_of(st.just(0.5), st.sampled_from([np.nan, np.inf, "half", [0.5, 0.5], None])),
       significance=st.one_of(st.just(1e-3), st.sampled_from([0.0, -1.0, 1.0, 1.5, np.nan, "x", True, 0.5])),
       n=st.one_of(st.just(16), st.sampled_from([0, -1, 2.5, "16", 1])),
       replicates=st.one_of(st.just(8), st.sampled_from([1, 0, 2.0, 2])))
def test_grader_arguments(exact, significance, n, replicates):
    """A grader's bad argument is the teacher's error (named), never a FAIL of
    the student's code: with a correct estimator, an accepted call passes or
    fails on statistics only."""
    est = lambda m, rng: rng.random(m).mean()                # noqa: E731 - a correct student

    def call(_):
        r = GR.grade_estimator(est, exact, n=n, replicates=replicates, significance=significance,
                               rng=1, verbose=False)
        assert "could not use" not in r.reason, r.reason
        return r.passed
    _holds("grade_estimator", call, None, ("exact", "significance", "n", "replicates"))

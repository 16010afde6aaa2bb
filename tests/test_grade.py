"""The graders of mcvar.testing.grade, and the course exercises graded by them.

Every exercise's reference solution must PASS, its planted wrong solution
must FAIL and its untouched stub must be NOT ATTEMPTED, so the graders
themselves are tested; every notebook with exercises has two or three, each
graded by one ``exercise(...)`` call. The answers live in ``tests/solutions``
and must not ship with the package: the last tests check the package's files.
"""
import ast
import importlib.resources
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mcvar import warps
from mcvar.bsdf import Lambertian
from mcvar.testing import bugs, exercise, exercises, grade, mutants
from mcvar.testing.exercises import EXERCISE_MAP, EXERCISES

from solutions import SOLUTIONS
from solutions.nb01_06 import LambertianSolution

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"


def test_every_exercise_has_its_answers_on_file():
    assert sorted(SOLUTIONS) == sorted(EXERCISES)


@pytest.mark.parametrize("name", list(EXERCISES))
def test_reference_solution_passes(name):
    r = exercise(name, *SOLUTIONS[name].reference, verbose=False)
    assert r.passed and r.status == "PASS", r


@pytest.mark.parametrize("name", list(EXERCISES))
def test_planted_wrong_solution_fails(name):
    sol = SOLUTIONS[name]
    r = exercise(name, *sol.wrong, verbose=False)
    assert not r.passed and r.status == "FAIL", (sol.mistake, r)
    assert r.reason and "NotImplementedError" not in r.reason


@pytest.mark.parametrize("name", list(EXERCISES))
def test_untouched_stub_is_not_attempted(name):
    r = exercise(name, *EXERCISES[name].stubs(), verbose=False)
    assert r.status == grade.NOT_ATTEMPTED and not r.passed


def _notebook_sources(nb):
    cells = json.loads(nb.read_text())["cells"]
    return "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")


def test_every_notebook_with_exercises_has_two_or_three_graded_ones():
    found = {}
    with_exercises = sorted({ex.notebook for ex in EXERCISES.values()})
    assert set(with_exercises) >= {f"{k:02d}" for k in range(1, 10)} | {"12"}
    for nb in sorted(NOTEBOOKS.glob("[0-9][0-9]_*.ipynb")):
        if nb.name[:2] not in with_exercises:
            continue
        names = re.findall(r'(?<![\w.])exercise\(\s*"([^"]+)"', _notebook_sources(nb))
        found[nb.name[:2]] = names
        assert 2 <= len(names) <= 3, f"{nb.name}: exercises {names}"
        for n in names:
            assert n in EXERCISES and EXERCISES[n].notebook == nb.name[:2], (nb.name, n)
    assert sorted(n for v in found.values() for n in v) == sorted(EXERCISES)


# --------------------------------------------------------------------------
# the answers do not ship

def _answer_names():
    """Names of every reference and planted wrong solution (functions, classes of objects)."""
    names = set()
    for sol in SOLUTIONS.values():
        for part in sol.reference + sol.wrong:
            obj = part if callable(part) and hasattr(part, "__name__") else type(part)
            if obj.__module__.startswith("solutions"):
                names.add(obj.__name__)
    return names


def _packaged_python_files():
    """The .py files a wheel of this project carries: setuptools' package
    discovery with pyproject.toml's own settings (what ``pip install .``
    installs; there is no package data)."""
    from setuptools import find_packages
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    packages = find_packages(where=str(ROOT), include=cfg["include"], exclude=cfg.get("exclude", ()))
    assert "mcvar" in packages and "mcvar.testing" in packages
    return packages, [p for pkg in packages for p in (ROOT / pkg.replace(".", "/")).glob("*.py")]


def test_a_wheel_carries_no_solutions():
    packages, files = _packaged_python_files()
    assert not [p for p in packages if not p.startswith("mcvar")], packages
    assert not any("solutions" in p for p in packages), packages
    answers = _answer_names()
    assert {"LambertianSolution", "FixedGlass", "bdpt_power_weight", "_jittered"} <= answers
    leaked = []
    for path in files:
        tree = ast.parse(path.read_text())
        for node in tree.body:                       # module-level definitions
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name in answers:
                leaked.append(f"{path.relative_to(ROOT)}: {node.name}")
    assert not leaked, leaked


def test_the_installed_package_tree_holds_no_answers():
    """Walk mcvar as installed (importlib.resources): no solutions module, and
    no exercise record carrying a reference or a wrong answer."""
    root = importlib.resources.files("mcvar")
    stack, seen = [root], []
    while stack:
        node = stack.pop()
        for child in node.iterdir():
            if child.is_dir():
                stack.append(child)
            elif child.name.endswith(".py"):
                seen.append(child.name)
                text = child.read_text()
                assert "tests/solutions" in text or "from solutions" not in text, child
    assert "exercises.py" in seen and "solutions.py" not in seen
    fields = exercises.Exercise.__dataclass_fields__
    assert not {"reference", "wrong", "mistake"} & set(fields)
    assert not hasattr(exercises, "LambertianSolution")


def test_student_exception_is_a_fail_naming_it(capsys):
    def broken(u):
        return 1.0 / 0.0

    r = grade.grade_warp(broken, warps.square_to_uniform_sphere_pdf, "sphere", rng=1)
    assert r.status == "FAIL" and "ZeroDivisionError" in r.reason
    assert capsys.readouterr().out.startswith("FAIL  warp: your code raised ZeroDivisionError")


def test_wrong_shape_is_a_fail_not_a_crash():
    r = grade.grade_warp(lambda u: u[:, :1], warps.square_to_uniform_sphere_pdf, "sphere", rng=1,
                         verbose=False)
    assert r.status == "FAIL" and "shape" in r.reason


def test_result_repr_and_fields():
    r = grade.grade_warp(warps.square_to_cosine_hemisphere, warps.square_to_cosine_hemisphere_pdf,
                         "hemisphere", n=50_000, rng=3, name="cosine", verbose=False)
    assert r.passed and repr(r).startswith("PASS  cosine: chi-square p = ")
    assert len(r.checks) == 2 and all(c.passed for c in r.checks)


@pytest.mark.parametrize("mutant", ["pdf_times_2", "sampler_missing_sin_theta", "table_index_past_end",
                                    "sphere_flip_without_half"])
def test_grade_warp_rejects_shipped_bugs(mutant):
    m = mutants.get(mutant)
    assert grade.grade_warp(m.correct_sample, m.correct_pdf, m.domain, n=100_000, rng=4,
                            verbose=False).passed
    assert not grade.grade_warp(m.sample, m.pdf, m.domain, n=100_000, rng=4, verbose=False).passed


def test_grade_bsdf_on_library_and_mutant():
    assert grade.grade_bsdf(Lambertian(0.5), n=50_000, rng=5, verbose=False).passed
    bad = grade.grade_bsdf(mutants.weight_without_cos(Lambertian(0.5)), n=50_000, rng=5, verbose=False)
    assert bad.status == "FAIL" and "weight" in bad.reason


def test_grade_estimator_zero_variance_claim():
    exact = lambda n, rng: 2.0                       # importance sampling proportional to f
    assert grade.grade_estimator(exact, 2.0, n=10, variance=0.0, rng=6, verbose=False).passed
    noisy = lambda n, rng: 2.0 + np.random.default_rng(rng).normal() / math.sqrt(n)
    r = grade.grade_estimator(noisy, 2.0, n=10, variance=0.0, rng=6, verbose=False)
    assert r.status == "FAIL" and "zero variance" in r.reason


def test_grade_estimator_wrong_variance_claim():
    # unbiased, per-sample variance 4 (the board), claimed 1: the variance test must reject
    est = SOLUTIONS["02.checkerboard"].reference[0]
    r = grade.grade_estimator(est, 2.0, n=1000, replicates=200, variance=1.0, rng=7, verbose=False)
    assert r.status == "FAIL" and r.reason.startswith("variance")


def test_grade_estimator_rgb():
    est = lambda n, rng: np.random.default_rng(rng).normal([1.0, 2.0, 3.0], 1.0, size=(n, 3)).mean(0)
    assert grade.grade_estimator(est, [1.0, 2.0, 3.0], n=100, rng=8, verbose=False).passed
    assert not grade.grade_estimator(est, [1.0, 2.0, 3.5], n=100, rng=8, verbose=False).passed


def test_grade_values_shape_and_mismatch():
    r = grade.grade_values(lambda c: c[:2], (np.ones(3),), np.ones(3), verbose=False)
    assert r.status == "FAIL" and "shape" in r.reason


def test_grade_sampler_library_sets():
    from mcvar import samplers
    assert grade.grade_sampler(samplers.n_rooks, 64, strata=(64, 1), replicates=50, rng=9, verbose=False).passed
    assert grade.grade_sampler(samplers.sobol, 256, net=8, replicates=20, rng=9, verbose=False).passed
    r = grade.grade_sampler(samplers.random, 64, strata=(8, 8), replicates=5, rng=9, verbose=False)
    assert r.status == "FAIL" and "not stratified" in r.reason


def test_grade_pixel_sampler_rejects_index_past_end():
    def upper_bound_unclamped(image, r):           # the lecture's upper_bound at r -> 1 on a dark last row
        cdf = np.cumsum(image.ravel() / image.sum())
        return np.searchsorted(cdf, r, side="right") + (r > 0.9999999)  # past the end for r near 1
    r = grade.grade_pixel_sampler(upper_bound_unclamped, EXERCISE_MAP, n=10_000, rng=10, verbose=False)
    assert r.status == "FAIL" and "outside" in r.reason


@pytest.mark.parametrize("call, match", [
    (lambda: grade.grade_warp(warps.square_to_uniform_sphere, warps.square_to_uniform_sphere_pdf, "cube"),
     "domain"),
    (lambda: grade.grade_consistent(lambda n, rng: 0.0, 0.0, [16]), "ns"),
    (lambda: grade.grade_estimator(lambda n, rng: 0.0, 0.0, n=4, replicates=1), "replicates"),
    (lambda: grade.grade_sampler(lambda n, rng: None, 10, net=3), "net"),
    (lambda: exercise("99.nothing", None), "name"),
    (lambda: exercise("01.jittered"), "argument"),
    (lambda: exercise("12.envmap_pdf", object()), "sample"),
])
def test_bad_grader_arguments_raise(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()


def test_lambertian_solution_matches_library():
    wo = np.array([[0.0, 1.0, 0.0]] * 4)
    wi = warps.square_to_cosine_hemisphere(np.random.default_rng(11).random((4, 2)))
    ref = LambertianSolution(0.8)
    np.testing.assert_allclose(ref.eval(wo, wi), Lambertian(0.8).eval(wo, wi)[:, 0], rtol=1e-14)
    np.testing.assert_allclose(ref.pdf(wo, wi), Lambertian(0.8).pdf(wo, wi), rtol=1e-14)


# --------------------------------------------------------------------------
# the graders added for notebooks 07-12, on independent implementations

def test_grade_dielectric_accepts_the_library_glass_and_rejects_schlick_and_constant_fresnel():
    from mcvar.bsdf import Glass
    assert grade.grade_dielectric(Glass(1.5), 1.5, rng=3, verbose=False).passed   # a second implementation
    r = grade.grade_dielectric(Glass(1.5, fresnel="schlick"), 1.5, rng=3, verbose=False)
    assert r.status == "FAIL" and "exact Fresnel" in r.reason                       # an approximation, 8 sigma off
    r = grade.grade_dielectric(Glass(1.5, fresnel=0.1), 1.5, rng=3, verbose=False)
    assert r.status == "FAIL" and "0 deg" in r.reason


def test_grade_dielectric_rejects_lost_energy_and_wrong_directions():
    glass = bugs.FresnelGlass(1.5)

    class Absorbing:
        def sample(self, wo, u):
            wi, w, p = glass.sample(wo, u)
            return wi, 0.9 * w, p

    class NoRefraction:
        def sample(self, wo, u):
            wi, w, p = glass.sample(wo, u)
            return wo * np.array([-1.0, 1.0, -1.0]), w, p

    r = grade.grade_dielectric(Absorbing(), 1.5, rng=4, verbose=False)
    assert r.status == "FAIL" and "weights must be 1" in r.reason
    r = grade.grade_dielectric(NoRefraction(), 1.5, rng=4, verbose=False)
    assert r.status == "FAIL" and "reflected" in r.reason


def _uniform_walk(x, rng):
    # a symmetric random walk on the torus: the uniform density is invariant, every move accepted
    return (x + 0.1 * np.random.default_rng(rng).standard_normal(x.shape)) % 1.0


def test_grade_chain_on_an_invariant_and_a_drifting_kernel():
    uniform = lambda x: np.ones(x.shape[0])
    ok = grade.grade_chain(_uniform_walk, lambda u: u, uniform, steps=5, n=50_000, rng=5, verbose=False)
    assert ok.passed, ok
    shrink = lambda x, rng: 0.9 * x                                 # drifts towards the corner
    bad = grade.grade_chain(shrink, lambda u: u, uniform, steps=5, n=50_000, rng=5, verbose=False)
    assert bad.status == "FAIL" and "no longer follow" in bad.reason
    stuck = grade.grade_chain(lambda x, rng: x, lambda u: u, uniform, steps=3, n=1000, rng=5, verbose=False)
    assert stuck.status == "FAIL" and "ever moved" in stuck.reason


def test_grade_coverage_of_iid_error_bars():
    h = np.random.default_rng(6).normal(0.5, 1.0, size=(400, 200))
    iid = lambda x: x.std(ddof=1) / math.sqrt(x.size)
    assert grade.grade_coverage(iid, h, 0.5, verbose=False).passed
    r = grade.grade_coverage(lambda x: 0.5 * iid(x), h, 0.5, verbose=False)
    assert r.status == "FAIL" and "too narrow" in r.reason
    r = grade.grade_coverage(lambda x: 3.0 * iid(x), h, 0.5, verbose=False)
    assert r.status == "FAIL" and "too wide" in r.reason


def test_exercise_harnesses_match_closed_forms():
    # the Jacobi exercise's exact radiosities solve B = E + rho F B; the photon value is f E(x0)
    b = exercises.JACOBI_EXACT
    np.testing.assert_allclose(b, exercises.JACOBI_E + exercises.JACOBI_RHO * (exercises.JACOBI_F @ b), rtol=1e-14)
    assert exercises.PHOTON_EXACT == pytest.approx(0.6 / math.pi * 3.0 * (2.0 / 3.0) * 1.3, rel=1e-15)
    # an AR(1) series with phi = 0.9 has lag-1 autocorrelation 0.9 and unit variance
    h = exercises.correlated_series(50, 4000, rng=7) - 0.5
    assert np.mean(h[:, 1:] * h[:, :-1]) / np.mean(h * h) == pytest.approx(0.9, abs=0.01)
    assert np.var(h) == pytest.approx(1.0, abs=0.05)


def test_find_the_bug_classes_render_without_nan_and_are_self_consistent():
    """The bugs are subtle: no NaN, no failed weight check, only the independent checks see them."""
    from mcvar.testing import check_weight_consistency
    ggx = bugs.GGXReflection(0.3)
    wo = np.array([0.3, 0.95, 0.0]) / np.linalg.norm([0.3, 0.95, 0.0])
    assert check_weight_consistency(ggx, wo, n=5000, rng=8).passed
    d = bugs.LatLongMap(bugs.BUG_MAP).sample(np.random.default_rng(9).random((1000, 2)))
    assert np.all(np.isfinite(d)) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    wi, w, p = bugs.FresnelGlass(1.5).sample(wo, np.random.default_rng(10).random((1000, 2)))
    assert np.all(w == 1.0) and np.all(np.isfinite(wi))


@pytest.mark.parametrize("call, match", [
    (lambda: grade.grade_dielectric(object(), 1.5), "sample"),
    (lambda: grade.grade_dielectric(bugs.FresnelGlass(), -1.0), "eta"),
    (lambda: grade.grade_dielectric(bugs.FresnelGlass(), 1.5, degrees=(95.0,)), "degrees"),
    (lambda: grade.grade_dielectric(bugs.FresnelGlass(), 1.5, n=0), "n"),
    (lambda: grade.grade_chain(None, lambda u: u, lambda x: x), "step"),
    (lambda: grade.grade_chain(_uniform_walk, lambda u: u, lambda x: x, steps=0), "steps"),
    (lambda: grade.grade_coverage(lambda h: 1.0, np.zeros((5, 10)), 0.0), "series"),
    (lambda: grade.grade_coverage(lambda h: 1.0, np.zeros((40, 10)), 0.0, level=1.5), "level"),
    (lambda: grade.grade_coverage(lambda h: 1.0, np.full((40, 10), np.nan), 0.0), "series"),
])
def test_bad_arguments_of_the_new_graders_raise(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()

"""The graders of mcvar.testing.grade, and the course exercises graded by them.

Every exercise's reference solution must PASS and its planted wrong solution
must FAIL, so the graders themselves are tested; every notebook ends with two
or three exercises, each graded by one ``exercise(...)`` call.
"""
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from mcvar import warps
from mcvar.bsdf import Lambertian
from mcvar.testing import exercise, grade, mutants
from mcvar.testing.exercises import EXERCISES, LambertianSolution

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.mark.parametrize("name", list(EXERCISES))
def test_reference_solution_passes(name):
    ex = EXERCISES[name]
    r = exercise(name, *ex.reference, verbose=False)
    assert r.passed and r.status == "PASS", r


@pytest.mark.parametrize("name", list(EXERCISES))
def test_planted_wrong_solution_fails(name):
    ex = EXERCISES[name]
    r = exercise(name, *ex.wrong, verbose=False)
    assert not r.passed and r.status == "FAIL", (ex.mistake, r)
    assert r.reason and "NotImplementedError" not in r.reason


def _stub(*args, **kwargs):
    raise NotImplementedError("write your solution here")


class _StubBSDF:
    eval = pdf = sample = staticmethod(_stub)


@pytest.mark.parametrize("name", list(EXERCISES))
def test_untouched_stub_is_not_attempted(name):
    ex = EXERCISES[name]
    stubs = [_StubBSDF() if part == "bsdf" else _stub for part in ex.parts]
    r = exercise(name, *stubs, verbose=False)
    assert r.status == grade.NOT_ATTEMPTED and not r.passed


def _notebook_sources(nb):
    cells = json.loads(nb.read_text())["cells"]
    return "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")


def test_every_notebook_ends_with_two_or_three_graded_exercises():
    found = {}
    for nb in sorted(NOTEBOOKS.glob("0[1-6]_*.ipynb")):
        names = re.findall(r'(?<![\w.])exercise\(\s*"([^"]+)"', _notebook_sources(nb))
        found[nb.name[:2]] = names
        assert 2 <= len(names) <= 3, f"{nb.name}: exercises {names}"
        for n in names:
            assert n in EXERCISES and EXERCISES[n].notebook == nb.name[:2], (nb.name, n)
    assert sorted(n for v in found.values() for n in v) == sorted(EXERCISES)


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
    est = EXERCISES["02.checkerboard"].reference[0]
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
    from mcvar.testing.exercises import EXERCISE_MAP

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

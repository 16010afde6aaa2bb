"""The samplers report writes every figure and CSV, with numbers that match the library."""
import csv
import math

import matplotlib.image as mpimg
import numpy as np
import pytest

from mcvar import discrepancy as D
from mcvar.cli import main
from mcvar.sampler_report import discrepancy_sweep, write_samplers_report
from mcvar.samplers import SAMPLERS, hammersley


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("samplers")
    return out, write_samplers_report(out, n=64, n_max=256, rng=3, progress=False)


def test_report_files(report):
    out, paths = report
    assert set(paths) == {"points", "spectra", "radial_spectra", "discrepancy",
                          "discrepancy_csv", "slopes_csv", "spectra_csv"}
    for key in ("points", "spectra", "radial_spectra", "discrepancy"):
        img = mpimg.imread(paths[key])
        assert paths[key].parent == out and img.ndim == 3 and min(img.shape[:2]) > 200


def test_report_numbers(report):
    _, paths = report
    rows = _read(paths["discrepancy_csv"])
    assert {r["sampler"] for r in rows} == set(SAMPLERS)
    # deterministic Hammersley: the CSV holds the exact star discrepancy
    ham = {int(r["n"]): float(r["star"]) for r in rows if r["sampler"] == "hammersley"}
    assert sorted(ham) == [16, 32, 64, 128, 256]
    for n, value in ham.items():
        assert value == pytest.approx(D.star(hammersley(n)), abs=1e-15)
    # grid and jittered only at perfect squares
    assert {int(r["n"]) for r in rows if r["sampler"] == "grid"} == {16, 64, 256}
    slopes = _read(paths["slopes_csv"])
    assert len(slopes) == 2 * len(SAMPLERS)
    for r in slopes:
        assert math.isfinite(float(r["slope"])) and float(r["slope_stderr"]) >= 0
        assert float(r["expected_star_slope"]) == SAMPLERS[r["sampler"]].star_slope
    spectra = {r["sampler"]: r for r in _read(paths["spectra_csv"])}
    # a k x k grid has no power off its lattice of spikes; blue noise has a dark centre
    assert float(spectra["grid"]["low_frequency_power"]) < 1e-12
    assert float(spectra["blue_noise"]["low_frequency_power"]) < float(spectra["random"]["low_frequency_power"])


def test_same_seed_same_numbers(tmp_path):
    a = discrepancy_sweep([16, 32], names=["random", "sobol"], replicates=2, rng=11)
    b = discrepancy_sweep([16, 32], names=["random", "sobol"], replicates=2, rng=11)
    c = discrepancy_sweep([16, 32], names=["random", "sobol"], replicates=2, rng=12)
    assert a == b and a != c
    assert all(r["replicates"] == 2 and r["star_se"] > 0 for r in a)


def test_cli_samplers(tmp_path, capsys):
    assert main(["samplers", "--n", "16", "--n-max", "64", "--out", str(tmp_path), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "points:" in printed and (tmp_path / "discrepancy.csv").exists()


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match="n must be >= 4"):
        write_samplers_report(tmp_path, n=2, progress=False)
    with pytest.raises(ValueError, match="n_max must be >= 16"):
        write_samplers_report(tmp_path, n=16, n_max=8, progress=False)
    with pytest.raises(TypeError, match="n must be an integer"):
        write_samplers_report(tmp_path, n=16.0, progress=False)
    with pytest.raises(ValueError, match="names must hold sampler names"):
        discrepancy_sweep([16], names=["nope"])
    with pytest.raises(ValueError, match="replicates must be >= 1"):
        discrepancy_sweep([16], replicates=0)
    assert main(["samplers", "--n", "0", "--out", str(tmp_path), "--quiet"]) == 2

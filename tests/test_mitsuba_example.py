"""The 'Is my renderer unbiased?' guide's Mitsuba 3 example, run where Mitsuba is installed."""
import importlib.util
import sys
from functools import partial
from pathlib import Path

import pytest

pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install -e '.[mitsuba]')")

from mcvar.experiments import Target, sweep  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "mitsuba_cornell.py"


@pytest.fixture(scope="module")
def example():
    sys.path.insert(0, str(EXAMPLE.parent))  # importable by name, as `mcvar converge --target` does
    try:
        yield importlib.import_module("mitsuba_cornell")
    finally:
        sys.path.remove(str(EXAMPLE.parent))


def test_mitsuba_path_tracer_measures_unbiased_and_fixed_depth_biased(example):
    # 16 x 16 pixels keep it to seconds; the guide's numbers are at 64 x 64
    target = Target(name="mitsuba-cornell-16", evaluate=partial(example.evaluate, res=16),
                    key="mitsuba-cornell;res=16", methods=("path", "path:2"), samplers=("independent",),
                    spp=(1, 4, 16, 64), reference_task=partial(example.reference, res=16, spp=512))
    r = sweep(target, replicates=6, seed=1, workers=1, progress=False)
    assert r.verdicts["path"].label == "both", r.verdicts["path"].evidence
    # depth 2 = direct light only: the indirect light is missing at every spp
    assert not r.verdicts["path:2"].unbiased and not r.verdicts["path:2"].consistent
    assert r.reference.value.shape == (16, 16, 3)


def test_example_rejects_unknown_methods(example):
    import numpy as np

    with pytest.raises(ValueError, match="method must be 'path'"):
        example.evaluate("bdpt", "independent", 1, np.random.default_rng(0), res=8)

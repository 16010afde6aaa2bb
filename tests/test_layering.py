"""The package's layering (docs/conventions.md): a module imports only from
layers below it, and matplotlib only in layer 7. Checked with ``ast``."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "mcvar"

LAYERS = {
    "_validation": 0,
    "samplers": 1, "geometry": 1, "metrics": 1, "images": 1,
    "discrepancy": 2, "warps": 2, "optics": 2,
    "bsdf": 3, "envmap": 3, "estimators": 3, "testing": 3,
    "examples": 4,
    "scene": 4, "tracer": 4,
    "integrators": 5, "radiosity": 5, "photons": 5,
    "experiments": 6,
    "plotting": 7, "report": 7, "sampler_report": 7, "cli": 7, "__main__": 7, "__init__": 7,
}


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).with_suffix("")
        yield path, rel.parts[0]


def _imports(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level >= 1:
                target = (node.module or "").split(".")[0]
                if target:
                    yield target
                else:  # "from . import x"
                    for alias in node.names:
                        yield alias.name
            elif node.module and node.module.split(".")[0] in ("mcvar", "matplotlib"):
                parts = node.module.split(".")
                yield parts[1] if parts[0] == "mcvar" and len(parts) > 1 else parts[0]
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "mcvar" and len(parts) > 1:
                    yield parts[1]
                elif parts[0] == "matplotlib":
                    yield "matplotlib"


@pytest.mark.parametrize("path,top", list(_modules()), ids=lambda v: str(v))
def test_module_imports_only_lower_layers(path, top):
    assert top in LAYERS, f"{top} has no layer: add it to LAYERS and docs/conventions.md"
    own = LAYERS[top]
    for target in _imports(path):
        if target == "matplotlib":
            assert own == 7, f"{path.name} imports matplotlib outside layer 7"
            continue
        if target == top or target not in LAYERS:
            continue
        allowed = LAYERS[target] < own or (own == 7 and LAYERS[target] == 7)
        assert allowed, f"{path.name} (layer {own}) imports {target} (layer {LAYERS[target]})"

"""The package's layering (docs/conventions.md): a module imports only from
layers below it, and matplotlib only in layer 7; inside a package, a module
imports only the modules of that package listed before it in PACKAGE_ORDER.
Checked with ``ast``."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "mcvar"

LAYERS = {
    "_validation": 0,
    "samplers": 1, "geometry": 1, "metrics": 1, "images": 1,
    "discrepancy": 2, "warps": 2, "optics": 2, "piecewise": 2,
    "bsdf": 3, "envmap": 3, "estimators": 3, "testing": 3,
    "examples": 4,
    "scene": 4, "tracer": 4,
    "mcmc": 4,
    "integrators": 5,
    "experiments": 6, "adaptive": 6,
    "plotting": 7, "report": 7, "sampler_report": 7, "chart_report": 7, "compare_report": 7, "cli": 7, "__main__": 7, "__init__": 7,
}

# The order of the modules inside each package: a module may import only the
# modules listed before it (``__init__`` comes last: it re-exports them all).
# Every module file of a package must be listed. A package that is still a
# single module on disk is skipped; ``None`` marks a package whose order has
# not been written yet (its test fails once it is a package on disk).
PACKAGE_ORDER = {
    "estimators": ["monte_carlo", "mis", "studies", "__init__"],
    "experiments": ["targets", "denoising", "runs", "reference", "analysis", "sweeps", "chart", "compare", "__init__"],
    "testing": ["_domains", "_chi2", "checks", "mutants", "grade", "exercises", "__init__"],
    "integrators": ["registry", "film", "stream", "emitters", "state", "lambertian", "path", "aov", "position", "light", "bdpt", "pssmlt", "radiosity", "photon", "sppm", "driver", "__init__"],
}


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).with_suffix("")
        yield path, rel.parts[0]


def _module_name(path):
    """Dotted name of the module in ``path`` and the package its relative imports start from."""
    parts = ("mcvar",) + path.relative_to(PKG).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
        return ".".join(parts), parts
    return ".".join(parts), parts[:-1]


def _is_module(dotted):
    rel = Path(*dotted.split(".")[1:]) if "." in dotted else Path()
    return (PKG / rel).with_suffix(".py").is_file() or (PKG / rel / "__init__.py").is_file()


def _absolute_imports(path):
    """Every mcvar module (dotted, absolute) and 'matplotlib' that ``path`` imports."""
    _, package = _module_name(path)
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level >= 1:
                base = package[:len(package) - (node.level - 1)]
                target = base + tuple(node.module.split(".")) if node.module else base
            elif node.module:
                target = tuple(node.module.split("."))
            else:
                continue
            if target[0] == "matplotlib":
                yield "matplotlib"
                continue
            if target[0] != "mcvar":
                continue
            # "from X import name": name may be a submodule of X
            subs = [".".join(target + (a.name,)) for a in node.names]
            found = [s for s in subs if _is_module(s)]
            yield from found
            if len(found) < len(subs):
                yield ".".join(target)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "matplotlib":
                    yield "matplotlib"
                elif parts[0] == "mcvar":
                    yield alias.name


def _imports(path):
    """Top-level mcvar modules (and 'matplotlib') imported by ``path``."""
    for target in _absolute_imports(path):
        if target == "matplotlib":
            yield target
        elif target != "mcvar":
            yield target.split(".")[1]


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


@pytest.mark.parametrize("package", sorted(PACKAGE_ORDER))
def test_modules_inside_a_package_import_only_earlier_ones(package):
    folder = PKG / package
    if not (folder / "__init__.py").is_file():
        pytest.skip(f"mcvar.{package} is not a package on disk (yet)")
    order = PACKAGE_ORDER[package]
    on_disk = sorted(p.stem for p in folder.glob("*.py"))
    assert order is not None, (f"mcvar.{package} is a package: write the order of its modules "
                               f"{on_disk} into PACKAGE_ORDER in tests/test_layering.py")
    assert sorted(order) == on_disk, (f"PACKAGE_ORDER[{package!r}] must list exactly the modules on disk; "
                                      f"missing {sorted(set(on_disk) - set(order))}, "
                                      f"not on disk {sorted(set(order) - set(on_disk))}")
    assert order[-1] == "__init__", f"PACKAGE_ORDER[{package!r}] must end with '__init__'"
    rank = {name: i for i, name in enumerate(order)}
    for name in order:
        path = folder / f"{name}.py"
        for target in _absolute_imports(path):
            parts = target.split(".")
            if parts[:2] != ["mcvar", package]:
                continue
            dep = parts[2] if len(parts) > 2 else "__init__"
            assert dep in rank and rank[dep] < rank[name], (
                f"mcvar/{package}/{name}.py imports {target}, which is not listed before "
                f"{name!r} in PACKAGE_ORDER[{package!r}] = {order}")


def test_the_import_checker_sees_relative_imports(tmp_path):
    # the checker itself: resolves "from .x", "from . import x", "from .. import y"
    mis = PKG / "estimators" / "mis.py"
    targets = set(_absolute_imports(mis))
    assert {"mcvar.estimators.monte_carlo", "mcvar._validation", "mcvar.warps"} <= targets
    init = set(_absolute_imports(PKG / "estimators" / "__init__.py"))
    assert {"mcvar.estimators.monte_carlo", "mcvar.estimators.mis", "mcvar.estimators.studies"} <= init

"""The package's layering (docs/conventions.md): a module imports only from
layers strictly below it, and matplotlib only from layer 7 on; inside a
package, a module imports only the modules of that package listed before it in
PACKAGE_ORDER (a method module of ``integrators`` that is not listed is a
*leaf*: it may import any listed module but ``__init__``, and only
``__init__`` may import it). Checked with ``ast``."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "mcvar"

LAYERS = {
    "_validation": 0,
    "samplers": 1, "geometry": 1, "metrics": 1, "images": 1,
    "discrepancy": 2, "warps": 2, "optics": 2, "piecewise": 2,
    "bsdf": 3, "envmap": 3, "estimators": 3, "testing": 3,
    "bvh": 3, "convex": 3,
    "scenefile": 3.5,
    "examples": 4, "lab_renderer": 4,
    "scene": 4, "tracer": 4, "tessellate": 4,
    "mcmc": 4,
    "integrators": 5, "interop": 5,
    "experiments": 6, "adaptive": 6,
    "plotting": 7, "pages": 7,
    "report": 8, "sampler_report": 8, "chart_report": 8, "compare_report": 8,
    "demo": 9,
    "cli": 10,
    "__main__": 11,
    "__init__": 0,   # mcvar/__init__.py holds the version only: it imports no mcvar module
}

#: Packages whose unlisted modules are leaves (a new method is one file, no edit here).
LEAF_PACKAGES = {"integrators"}

# The order of the modules inside each package: a module may import only the
# modules listed before it (``__init__`` comes last: it re-exports them all).
# Every module file of a package must be listed. A package that is still a
# single module on disk is skipped; ``None`` marks a package whose order has
# not been written yet (its test fails once it is a package on disk).
PACKAGE_ORDER = {
    "estimators": ["monte_carlo", "mis", "studies", "__init__"],
    "experiments": ["targets", "denoising", "runs", "reference", "analysis", "sweeps", "chart", "compare_args", "scene_references", "equal_time", "compare_matrix", "view_independence", "slide_pairs", "compare", "__init__"],
    "testing": ["_domains", "_chi2", "checks", "mutants", "bugs", "grade", "exercises", "__init__"],
    "scenefile": ["xml", "mesh", "props", "lights", "build", "write", "__init__"],
    "interop": ["mitsuba", "__init__"],
    "integrators": ["registry", "knobs", "emitters", "settings", "film", "stream", "directions", "state", "reuse", "lambertian", "path", "aov", "position", "light", "caustics", "bdpt", "pssmlt", "mmlt_lambertian", "mmlt_states", "mmlt", "radiosity", "photon", "sppm", "allocation", "driver", "__init__"],
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


# The one import against the layers: mcvar.scene.save_scene writes a Scene through
# the exporter of mcvar.interop.mitsuba (issue 23: one mapping from Scene to
# Mitsuba, not two), which itself needs mcvar.scene; it is imported inside the
# function, when called.
UPWARD = {("scene", "interop")}


@pytest.mark.parametrize("path,top", list(_modules()), ids=lambda v: str(v))
def test_module_imports_only_lower_layers(path, top):
    assert top in LAYERS, f"{top} has no layer: add it to LAYERS and docs/conventions.md"
    own = LAYERS[top]
    for target in _imports(path):
        if target == "matplotlib":
            assert own >= 7, f"{path.name} imports matplotlib below layer 7"
            continue
        if target == top or target not in LAYERS or (top, target) in UPWARD:
            continue
        assert LAYERS[target] < own, f"{path.name} (layer {own}) imports {target} (layer {LAYERS[target]})"


@pytest.mark.parametrize("package", sorted(PACKAGE_ORDER))
def test_modules_inside_a_package_import_only_earlier_ones(package):
    folder = PKG / package
    if not (folder / "__init__.py").is_file():
        pytest.skip(f"mcvar.{package} is not a package on disk (yet)")
    order = PACKAGE_ORDER[package]
    on_disk = sorted(p.stem for p in folder.glob("*.py"))
    assert order is not None, (f"mcvar.{package} is a package: write the order of its modules "
                               f"{on_disk} into PACKAGE_ORDER in tests/test_layering.py")
    leaves = sorted(set(on_disk) - set(order)) if package in LEAF_PACKAGES else []
    assert sorted(order + leaves) == on_disk, (
        f"PACKAGE_ORDER[{package!r}] must list exactly the modules on disk; "
        f"missing {sorted(set(on_disk) - set(order))}, not on disk {sorted(set(order) - set(on_disk))}")
    assert order[-1] == "__init__", f"PACKAGE_ORDER[{package!r}] must end with '__init__'"
    # a leaf ranks after every listed module and before __init__
    full = order[:-1] + leaves + ["__init__"]
    rank = {name: i for i, name in enumerate(full)}
    for name in full:
        path = folder / f"{name}.py"
        for target in _absolute_imports(path):
            parts = target.split(".")
            if parts[:2] != ["mcvar", package]:
                continue
            dep = parts[2] if len(parts) > 2 else "__init__"
            assert dep not in leaves or name == "__init__", (
                f"mcvar/{package}/{name}.py imports the leaf module {target}: only __init__ may "
                f"(list {dep!r} in PACKAGE_ORDER[{package!r}] if other modules build on it)")
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


def test_a_new_method_module_is_a_leaf_without_an_edit_here(tmp_path, monkeypatch):
    """A method module that PACKAGE_ORDER does not list is accepted as a leaf, and a
    listed module importing it is refused (the checker run on a copy of the package)."""
    import shutil

    copy = tmp_path / "mcvar"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "integrators" / "toy_leaf.py").write_text("from .registry import register\n")
    monkeypatch.setitem(globals(), "PKG", copy)
    test_modules_inside_a_package_import_only_earlier_ones("integrators")
    (copy / "integrators" / "film.py").write_text("from . import toy_leaf\n")
    with pytest.raises(AssertionError, match="leaf module"):
        test_modules_inside_a_package_import_only_earlier_ones("integrators")

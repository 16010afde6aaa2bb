"""The package's shape, measured with ``ast`` over ``mcvar/`` (issue 20): no
function longer than 150 lines, at most 5 functions with more than 8
parameters, and no import cycle among mcvar modules (imports made inside
functions count: a cycle is a cycle whenever it closes)."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "mcvar"

MAX_LINES = 150
MAX_PARAMS = 8
MAX_WIDE_FUNCTIONS = 5


def _functions():
    """(module path, qualified name, lines, parameters) of every function and method."""
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        stack = [(tree, "")]
        while stack:
            node, prefix = stack.pop()
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    a = child.args
                    n = (len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
                         + (a.vararg is not None) + (a.kwarg is not None))
                    name = prefix + child.name
                    yield path.relative_to(PKG.parent), name, child.end_lineno - child.lineno + 1, n
                    stack.append((child, name + "."))
                elif isinstance(child, ast.ClassDef):
                    stack.append((child, prefix + child.name + "."))
                else:
                    stack.append((child, prefix))


def _module_name(path: Path) -> tuple[str, tuple]:
    """Dotted name of the module in ``path`` and the package its relative imports start from."""
    parts = ("mcvar",) + path.relative_to(PKG).with_suffix("").parts
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), parts[:-1]
    return ".".join(parts), parts[:-1]


def _is_module(dotted: str) -> bool:
    rel = Path(*dotted.split(".")[1:]) if "." in dotted else Path()
    return (PKG / rel).with_suffix(".py").is_file() or (PKG / rel / "__init__.py").is_file()


def _imports(path: Path) -> set:
    """Every mcvar module ``path`` imports, anywhere in the file (functions included),
    except under ``if TYPE_CHECKING:`` (annotations only: never executed)."""
    _, package = _module_name(path)
    found = set()
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for top in ast.walk(tree) if isinstance(top, ast.If)
                   and getattr(top.test, "id", getattr(top.test, "attr", None)) == "TYPE_CHECKING"
                   for n in ast.walk(top)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                target = base + tuple(node.module.split(".")) if node.module else base
            elif node.module:
                target = tuple(node.module.split("."))
            else:
                continue
            if target[0] != "mcvar":
                continue
            subs = [".".join(target + (a.name,)) for a in node.names]
            modules = [s for s in subs if _is_module(s)]
            found.update(modules)
            if len(modules) < len(subs):
                found.add(".".join(target))
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "mcvar")
    return {m for m in found if _is_module(m)}


def import_graph() -> dict:
    """module -> the mcvar modules it imports (a package's import is its ``__init__``)."""
    graph = {}
    for path in sorted(PKG.rglob("*.py")):
        name, _ = _module_name(path)
        graph[name] = _imports(path) - {name}
    return graph


def find_cycle(graph: dict):
    """One import cycle as a list of modules (first == last), or None (iterative DFS)."""
    state = {}
    for root in sorted(graph):
        if state.get(root):
            continue
        stack, trail = [(root, iter(sorted(graph.get(root, ()))))], [root]
        state[root] = 1
        while stack:
            node, children = stack[-1]
            for child in children:
                if state.get(child) == 1:
                    return trail[trail.index(child):] + [child]
                if not state.get(child):
                    state[child] = 1
                    trail.append(child)
                    stack.append((child, iter(sorted(graph.get(child, ())))))
                    break
            else:
                state[node] = 2
                trail.pop()
                stack.pop()
    return None


def test_no_function_is_longer_than_150_lines():
    long = [f"{p}:{name} ({lines} lines)" for p, name, lines, _ in _functions() if lines > MAX_LINES]
    assert not long, f"functions over {MAX_LINES} lines: {long}"


def test_at_most_five_functions_take_more_than_8_parameters():
    wide = [f"{p}:{name} ({n} parameters)" for p, name, _, n in _functions() if n > MAX_PARAMS]
    assert len(wide) <= MAX_WIDE_FUNCTIONS, (
        f"{len(wide)} functions take more than {MAX_PARAMS} parameters (at most {MAX_WIDE_FUNCTIONS} "
        f"may; pass a settings dataclass instead): {wide}")


def test_no_import_cycle_among_mcvar_modules():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


# ---------------------------------------------------------------- the checkers themselves

def test_the_cycle_finder_finds_a_planted_cycle_and_only_then():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"x": set(), "a": {"b"}, "b": {"a"}}) == ["a", "b", "a"]


def test_imports_inside_functions_are_seen():
    graph = import_graph()
    # experiments.chart imports the integrators inside functions only
    assert "mcvar.integrators" in graph["mcvar.experiments.chart"]
    assert "mcvar._validation" in graph["mcvar.samplers"]


def test_the_function_walker_counts_keyword_only_and_star_arguments(tmp_path):
    src = "def f(a, /, b, *c, d, e=1, **g):\n    pass\n"
    node = ast.parse(src).body[0]
    a = node.args
    n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    assert n == 6


# ---------------------------------------------------------------- state lives in objects

#: Module-level caches still owned by the render driver's half of issue 20 (helper drv
#: moves them into the render / the worker pool); delete an entry once it is gone.
PENDING_CACHES: set = set()
#: Memoized pure tables (a function of their argument only, read-only arrays) and the
#: version of the on-disk run cache: not state.
PURE_TABLES = {"mcvar/testing/_domains.py:_gauss_legendre", "mcvar/experiments/runs.py:CACHE_VERSION"}


def test_no_module_level_caches():
    """No module-level dict named like a cache and no ``lru_cache``/``cache`` decorator: a
    cache belongs to an object with a lifetime (a target owns its scene, a scene the
    images of its visible lights, a render its tracer)."""
    found = []
    for path in sorted(PKG.rglob("*.py")):
        rel = str(path.relative_to(PKG.parent))
        tree = ast.parse(path.read_text())
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else (
                [node.target] if isinstance(node, ast.AnnAssign) else [])
            for t in targets:
                if isinstance(t, ast.Name) and any(w in t.id.upper() for w in ("CACHE", "TRACERS", "IMAGES")):
                    found.append(f"{rel}:{t.id}")
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for dec in node.decorator_list:
                    name = ast.unparse(dec.func if isinstance(dec, ast.Call) else dec)
                    if name.split(".")[-1] in ("lru_cache", "cache"):
                        found.append(f"{rel}:{node.name}")
    stray = sorted(set(found) - PENDING_CACHES - PURE_TABLES)
    assert not stray, f"module-level caches (give them an owner with a lifetime): {stray}"


def test_visible_lights_images_are_cached_by_their_scene():
    from mcvar.integrators.emitters import VisibleLights
    from mcvar.scene import load_scene

    scene = load_scene("cornell")
    image = VisibleLights(scene).image((8, 8))
    assert VisibleLights(scene).image((8, 8)) is image          # the scene's own cache, across instances
    other = VisibleLights(load_scene("cornell")).image((8, 8))
    assert other is not image and (other == image).all()        # another scene object computes its own

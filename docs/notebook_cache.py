"""The executed course notebooks' cache, shared by the docs build and the tests.

``docs/hooks.py`` adds every notebook to the site with its outputs, executed
in a scratch folder and cached in ``.cache/notebooks`` under a key of the
notebook's bytes and of every file in ``mcvar/``; ``tests/test_notebooks.py``
executes every notebook too, and stores what it executed under the same key,
so that a docs build after the tests (as in ``.ci/run``) executes nothing
again. Not part of the mcvar package; imports neither mkdocs nor pytest.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
PACKAGE = ROOT / "mcvar"
CACHE = ROOT / ".cache" / "notebooks"


def sources_digest() -> str:
    """A hash of every file of the mcvar package (a change anywhere invalidates the cache)."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            h.update(str(path.relative_to(PACKAGE)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def cached_copy(source: Path, digest: str | None = None) -> Path:
    """Where the executed copy of notebook ``source`` is cached."""
    digest = sources_digest() if digest is None else digest
    key = hashlib.sha256(Path(source).read_bytes() + digest.encode()).hexdigest()[:16]
    return CACHE / key / "course" / Path(source).name


def store(nb, target: Path) -> None:
    """Write the executed notebook ``nb`` to ``target`` atomically (parallel writers are safe)."""
    import nbformat

    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f"{target.name}.{os.getpid()}.tmp")
    nbformat.write(nb, tmp)
    tmp.replace(target)

"""MkDocs hook: the course notebooks (executed, with outputs) and the API pages.

Loaded by ``hooks:`` in mkdocs.yml; not part of the mcvar package.

* **Course.** Every ``notebooks/*.ipynb`` is executed (two at a time, each in
  a scratch folder, so the source notebooks stay output-free) and the
  executed copy is added to the site as ``course/NAME.ipynb``, rendered with
  its outputs by mkdocs-jupyter. Executed copies are cached in
  ``.cache/notebooks`` under a hash of the notebook and of every file in
  ``mcvar/`` (``docs/notebook_cache.py``, which the notebook tests fill
  too): a rebuild with nothing changed, or a build after the tests,
  executes nothing. A new notebook
  appears in the nav's *Course* section by itself (sorted by file name; its
  title is its first heading).
* **API reference.** One generated page ``api/MODULE.md`` per public module
  or package of ``mcvar`` (new modules appear by themselves). A guide page
  may end with its ``::: mcvar.MODULE`` block (with mkdocstrings options):
  the block moves to the API page, and the guide page shows a link in its
  place, so every object is rendered once. A module without such a block
  gets a plain ``::: mcvar.MODULE``.
* **Performance.** ``performance.md`` joins the nav when the file exists.

The nav in mkdocs.yml holds the placeholders ``course/`` and ``api/``
(sections filled here) and every hand-written page.
"""
from __future__ import annotations

import json
import logging
import os
import re
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

sys.path.insert(0, str(Path(__file__).resolve().parent))
import notebook_cache  # noqa: E402  (docs/notebook_cache.py, beside this hook)

log = logging.getLogger("mkdocs.hooks.mcvar")

ROOT = notebook_cache.ROOT
NOTEBOOKS = notebook_cache.NOTEBOOKS
PACKAGE = notebook_cache.PACKAGE
#: Seconds one cell may run before the docs build fails.
CELL_TIMEOUT = 600
#: Notebooks executed at once (each runs in its own kernel process).
PARALLEL = 2

_state: dict = {}


def _title(path: Path) -> str:
    nb = json.loads(path.read_text(encoding="utf-8"))
    for cell in nb.get("cells", []):
        if cell.get("cell_type") == "markdown":
            text = "".join(cell.get("source", []))
            m = re.search(r"^#\s+(.+)$", text, flags=re.M)
            if m:
                title = m.group(1).strip()
                number = re.match(r"^(\d+)_", path.stem)
                if number and not title.startswith(number.group(1)):
                    title = f"{number.group(1)} · {title}"  # the course order, as the other titles show it
                return title
    return path.stem.replace("_", " ")


def _execute(source: Path, target: Path) -> None:
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(source, as_version=4)
    with tempfile.TemporaryDirectory(prefix="mcvar-docs-nb-") as scratch:
        env_path = os.environ.get("PYTHONPATH", "")
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env_path) if p)
        NotebookClient(nb, timeout=CELL_TIMEOUT, kernel_name="python3",
                       resources={"metadata": {"path": scratch}}).execute()
    notebook_cache.store(nb, target)


def _executed_notebooks() -> list[tuple[Path, Path]]:
    """(source, executed copy) for every notebook; runs those not cached."""
    digest = notebook_cache.sources_digest()
    pairs = [(source, notebook_cache.cached_copy(source, digest)) for source in sorted(NOTEBOOKS.glob("*.ipynb"))]
    todo = [(s, t) for s, t in pairs if not t.is_file()]
    if todo:
        log.info("executing %d notebook(s) for the course pages", len(todo))
        with ThreadPoolExecutor(max_workers=PARALLEL) as pool:
            for f in [pool.submit(_execute, s, t) for s, t in todo]:
                f.result()  # a failing cell fails the build, naming it
    return pairs


_BLOCK = re.compile(r"^:::[ \t]+mcvar\.([A-Za-z0-9_]+)[\w.]*[ \t]*\n(?:(?:[ \t]+\S.*)?\n)*", flags=re.M)


def _api_blocks(docs_dir: Path) -> dict[str, list[tuple[str, str]]]:
    """module -> [(guide page, its ``::: mcvar.module...`` block with options)]."""
    found: dict[str, list[tuple[str, str]]] = {}
    for page in sorted(docs_dir.rglob("*.md")):
        rel = page.relative_to(docs_dir).as_posix()
        if rel.startswith("api/"):
            continue
        for m in _BLOCK.finditer(page.read_text(encoding="utf-8") + "\n"):
            found.setdefault(m.group(1), []).append((rel, m.group(0).rstrip() + "\n"))
    return found


def _public_modules() -> list[str]:
    names = []
    for path in sorted(PACKAGE.iterdir()):
        name = path.stem if path.suffix == ".py" else path.name
        if name.startswith("_") or (path.is_dir() and not (path / "__init__.py").is_file()):
            continue
        if path.suffix == ".py" or path.is_dir():
            names.append(name)
    return names


def _fill(nav, name: str, entries: list) -> bool:
    """Replace the placeholder ``name`` (a section whose value is ``name``) in ``nav``."""
    for i, item in enumerate(nav):
        if isinstance(item, dict):
            for title, value in item.items():
                if value == name:
                    nav[i] = {title: entries}
                    return True
                if isinstance(value, list) and _fill(value, name, entries):
                    return True
    return False


def on_config(config):
    docs_dir = Path(config["docs_dir"])
    notebooks = _executed_notebooks()
    blocks = _api_blocks(docs_dir)
    api = {}
    for m in _public_modules():
        own = blocks.get(m, [])
        guide = "".join(f"Guide: [{Path(p).stem}](../{p}).\n\n" for p in dict.fromkeys(p for p, _ in own))
        api[m] = f"# mcvar.{m}\n\n{guide}" + ("\n".join(b for _, b in own) or f"::: mcvar.{m}\n")
    _state.update(notebooks=notebooks, api=api)
    nav = config["nav"]
    if nav is not None:
        _fill(nav, "course/", [{_title(s): f"course/{s.name}"} for s, _ in notebooks])
        _fill(nav, "api/", [{f"mcvar.{m}": f"api/{m}.md"} for m in api])
        if (docs_dir / "performance.md").is_file() and not any(
                "performance.md" in str(item) for item in nav):
            nav.append({"Performance": "performance.md"})
    return config


@event_priority(100)  # before mkdocs-jupyter wraps the notebooks
def on_files(files, config):
    for source, executed in _state["notebooks"]:
        files.append(File(f"course/{source.name}", src_dir=str(executed.parent.parent),
                          dest_dir=config["site_dir"], use_directory_urls=config["use_directory_urls"]))
    for m, content in _state["api"].items():
        files.append(File.generated(config, f"api/{m}.md", content=content))
    return files


def on_page_markdown(markdown, page, config, files):
    """In a guide page, replace each ``::: mcvar.X`` block by a link to ``api/X.md``
    (the block itself moved there in :func:`on_config`)."""
    src = page.file.src_uri
    if src.startswith("api/") or not src.endswith(".md"):
        return markdown
    up = "../" * src.count("/")

    def link(m):
        mod = m.group(1)
        return f"Every public name of `mcvar.{mod}` with its docstring: [API reference]({up}api/{mod}.md).\n"

    seen = set()

    def once(m):  # one link per module even when the page had several blocks
        if m.group(1) in seen:
            return ""
        seen.add(m.group(1))
        return link(m)

    return _BLOCK.sub(once, markdown + "\n")

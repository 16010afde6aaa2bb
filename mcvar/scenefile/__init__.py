"""Scenes from files: Mitsuba 3 XML with OBJ and PLY meshes (layer 3.5; issue 23).

:func:`read_scene_file` parses a file (or a string) into the fields of a
:class:`mcvar.scene.Scene`; :func:`mcvar.scene.load_scene` builds the Scene
from them, and :func:`mcvar.scene.save_scene` writes a Scene back
(:func:`write_xml` serialises a Mitsuba scene dictionary). The package does
not import :mod:`mcvar.scene`: it sits between the materials (layer 3) and
the scenes (layer 4). docs/scene-files.md has the supported subset.
"""
from __future__ import annotations

from pathlib import Path

from .build import IOR, SUPPORTED, scene_fields
from .mesh import MeshError, read_mesh, read_obj, read_ply
from .write import LookAt, Rotate, write_xml
from .xml import Node, SceneFileError, parse_xml

__all__ = ["read_scene_file", "read_scene_string", "SceneFileError", "MeshError", "read_obj", "read_ply",
           "read_mesh", "parse_xml", "write_xml", "LookAt", "Rotate", "scene_fields", "SUPPORTED", "IOR", "Node"]


def read_scene_file(path, **overrides) -> dict:
    """The Scene fields of the Mitsuba 3 XML file ``path`` (``overrides`` replace its ``<default>`` values)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneFileError(f"{path}: cannot read the scene file ({exc.strerror or exc})") from None
    root = parse_xml(text, source=str(path), directory=path.resolve().parent, overrides=overrides)
    fields = scene_fields(root)
    fields["name"] = path.stem
    fields["description"] = root.meta.get("description", f"Mitsuba 3 scene file {path.name}")
    return fields


def read_scene_string(text: str, *, directory=None, **overrides) -> dict:
    """:func:`read_scene_file` for XML held in a string (relative file names from ``directory``)."""
    root = parse_xml(text, source="<string>", directory=directory, overrides=overrides)
    fields = scene_fields(root)
    fields["name"] = "scene"
    fields["description"] = "Mitsuba 3 scene (string)"
    return fields

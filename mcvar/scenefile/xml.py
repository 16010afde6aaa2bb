"""Mitsuba 3 XML read into a tree of plugins, with line numbers (layer 3.5).

The first half of :func:`mcvar.scene.load_scene` for files: the XML is
parsed with :mod:`xml.parsers.expat` (which reports the line of every
element), ``<default>`` values and ``$name`` substitutions are applied, and
every element becomes a :class:`Node`. Nothing here knows what a Scene is;
:mod:`mcvar.scenefile.build` turns the tree into one.

Every error is a :class:`SceneFileError` (a ``ValueError``) that names the
file, the line and the element, and says what is supported.
"""
from __future__ import annotations

import math
import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["SceneFileError", "Node", "parse_xml", "parse_transform", "PLUGIN_TAGS", "PROPERTY_TAGS"]

#: Elements that declare a plugin object (``type`` attribute), and may be nested.
PLUGIN_TAGS = ("integrator", "sensor", "film", "rfilter", "sampler", "shape", "bsdf", "emitter", "texture")
#: Elements that set one named property of the plugin they are in.
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform")
#: Child elements of ``<transform>``, applied in the order they appear.
TRANSFORM_TAGS = ("translate", "rotate", "scale", "matrix", "lookat")


class SceneFileError(ValueError):
    """A scene file that mcvar cannot read: the message names the file, the line and the element."""


@dataclass
class Node:
    """One XML element: ``tag``, attributes (``$name`` already substituted), children, line.

    ``source`` is the file (or ``'<string>'``) for messages; ``directory`` is
    where relative file names (meshes, images) are looked up.
    """

    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)
    source: str = "<string>"
    directory: Path = field(default_factory=Path.cwd)
    #: ``key="value"`` pairs of ``<!-- mcvar ... -->`` comments directly in <scene>
    meta: dict = field(default_factory=dict)

    @property
    def type(self):
        return self.attrs.get("type")

    @property
    def name(self):
        return self.attrs.get("name")

    def where(self) -> str:
        kind = f" type={self.type!r}" if self.type else ""
        name = f" name={self.name!r}" if self.name else ""
        return f"{self.source}:{self.line}: <{self.tag}{kind}{name}>"

    def error(self, message: str) -> SceneFileError:
        return SceneFileError(f"{self.where()}: {message}")

    def require(self, key: str) -> str:
        if key not in self.attrs:
            raise self.error(f"missing attribute {key!r}")
        return self.attrs[key]


_META = re.compile(r"\s*mcvar\s+(.*)", re.S)
#: What a ``<!-- mcvar key="value" -->`` comment inside <scene> may set (Mitsuba ignores comments):
#: the secondary-ray offset, the description and the pixel size of a constant environment
#: (``"height width"``; it changes how the environment is sampled, not its radiance).
META_KEYS = ("ray_epsilon", "description", "environment_size")

_SUB = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def parse_xml(text: str, *, source: str = "<string>", directory=None, overrides=None) -> Node:
    """Parse Mitsuba 3 XML ``text`` into the root ``<scene>`` :class:`Node`.

    Parameters
    ----------
    text : str
        The file's content.
    source : str
        The file name used in messages.
    directory : path, optional
        Where relative file names are resolved (default: the working directory).
    overrides : dict, optional
        Values replacing ``<default name=... value=...>`` entries, like
        ``mitsuba -D name=value`` (:func:`mitsuba.load_file`'s keywords). A
        name that no ``<default>`` declares is an error.

    Notes
    -----
    ``<default>`` elements must be direct children of ``<scene>`` and come
    before their use (Mitsuba's rule); ``$name`` is replaced in every
    attribute value of the elements that follow. ``<include>``, ``<path>``
    and ``<alias>`` are not supported (an error naming their line).
    """
    directory = Path.cwd() if directory is None else Path(directory)
    overrides = {} if overrides is None else {str(k): str(v) for k, v in dict(overrides).items()}
    parser = xml.parsers.expat.ParserCreate()
    stack: list[Node] = []
    root: list[Node] = []
    defaults: dict[str, str] = {}

    def start(tag, attrs):
        line = parser.CurrentLineNumber
        node = Node(tag, {}, line, source=source, directory=directory)
        for key, value in attrs.items():
            node.attrs[key] = _substitute(value, defaults, node)
        if not stack:
            if tag != "scene":
                raise node.error("the root element must be <scene version=\"3.x\">")
            version = node.require("version")
            if not re.fullmatch(r"3(\.\d+){0,2}", version.strip()):
                raise node.error(f"version must be 3.x (a Mitsuba 3 file); got {version!r} "
                                 "(Mitsuba 0.6 / 2 files need converting first)")
            root.append(node)
        else:
            if tag == "default":
                if len(stack) != 1:
                    raise node.error("<default> must be a direct child of <scene>")
                name, value = node.require("name"), node.require("value")
                defaults[name] = overrides.get(name, value)
            stack[-1].children.append(node)
        stack.append(node)

    def end(tag):
        stack.pop()

    def comment(text):
        m = _META.match(text)
        if m and len(stack) == 1:
            for key, value in re.findall(r'([A-Za-z_]+)="([^"]*)"', m.group(1)):
                if key not in META_KEYS:
                    raise SceneFileError(f"{source}:{parser.CurrentLineNumber}: unknown mcvar comment key "
                                         f"{key!r}; known: {', '.join(META_KEYS)}")
                stack[0].meta[key] = value

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CommentHandler = comment
    try:
        parser.Parse(text, True)
    except xml.parsers.expat.ExpatError as exc:
        raise SceneFileError(f"{source}:{exc.lineno}: not well-formed XML ({xml.parsers.expat.errors.messages.get(exc.code, exc)})") from None
    if not root:
        raise SceneFileError(f"{source}: no <scene> element")
    unknown = sorted(set(overrides) - set(defaults))
    if unknown:
        raise SceneFileError(f"{source}: options {unknown} name no <default> of the file "
                             f"(its defaults: {sorted(defaults) or 'none'})")
    return root[0]


def _substitute(value: str, defaults: dict, node: Node) -> str:
    def repl(m):
        name = m.group(1)
        if name not in defaults:
            raise node.error(f"${name} is not defined by a <default name={name!r} .../> above this line")
        return defaults[name]
    return _SUB.sub(repl, value)


# --------------------------------------------------------------------------
# property values

def parse_float(node: Node, key: str = "value") -> float:
    text = node.require(key)
    try:
        return float(text)
    except ValueError:
        raise node.error(f"{key}={text!r} is not a number") from None


def parse_numbers(node: Node, text: str, what: str, count=None) -> np.ndarray:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    try:
        values = np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise node.error(f"{what}={text!r} is not a list of numbers") from None
    if count is not None and values.size not in (count if isinstance(count, tuple) else (count,)):
        raise node.error(f"{what} needs {count} numbers; got {values.size} in {text!r}")
    if not np.all(np.isfinite(values)):
        raise node.error(f"{what}={text!r} must be finite")
    return values


def parse_vector(node: Node) -> np.ndarray:
    """``<point>``/``<vector>``/``<translate>``: ``value="x, y, z"`` or ``x=``, ``y=``, ``z=``."""
    if "value" in node.attrs:
        v = parse_numbers(node, node.attrs["value"], "value", (1, 3))
        return np.repeat(v, 3) if v.size == 1 else v
    if not any(k in node.attrs for k in "xyz"):
        raise node.error("needs value=\"x, y, z\" or x=, y=, z= attributes")
    return np.array([parse_float(node, k) if k in node.attrs else 0.0 for k in "xyz"])


def _rotation(axis, angle_deg):
    """Rotation matrix about ``axis`` by ``angle_deg`` (right-handed, Rodrigues)."""
    a = axis / np.linalg.norm(axis)
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) * c + s * k + (1.0 - c) * np.outer(a, a)


def look_at_matrix(origin, target, up, node: Node) -> np.ndarray:
    """Mitsuba's ``lookat``: camera space +z towards ``target``, +y towards ``up``, +x = up x dir (left)."""
    d = target - origin
    if not np.linalg.norm(d) > 0:
        raise node.error("lookat: target must differ from origin")
    d = d / np.linalg.norm(d)
    left = np.cross(up, d)
    if not np.linalg.norm(left) > 0:
        raise node.error("lookat: up must not be parallel to target - origin")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def parse_transform(node: Node) -> np.ndarray:
    """A ``<transform>`` element as a 4x4 matrix, its operations applied in order.

    Mitsuba's rule: each operation is applied after the ones above it, so
    ``<translate/><rotate/>`` is ``R @ T``. ``rotate`` takes ``angle`` in
    degrees about the axis ``x=, y=, z=``; ``scale`` takes
    ``value`` (one number: uniform) or ``x=, y=, z=`` (missing ones 1);
    ``matrix`` 16 numbers row by row (or 9 for a 3x3); ``lookat`` ``origin``,
    ``target`` and optional ``up``.
    """
    m = np.eye(4)
    for child in node.children:
        op = np.eye(4)
        if child.tag == "translate":
            op[:3, 3] = parse_vector(child)
        elif child.tag == "rotate":
            axis = np.array([parse_float(child, k) if k in child.attrs else 0.0 for k in "xyz"])
            if not abs(np.linalg.norm(axis) - 1.0) <= 1e-6:
                # Mitsuba 3 uses the axis as given: a longer one scales as it rotates
                raise child.error(f"rotate needs a unit axis (x=, y=, z=; Mitsuba 3 does not normalise it); "
                                  f"got length {np.linalg.norm(axis):g}")
            op[:3, :3] = _rotation(axis, parse_float(child, "angle"))
        elif child.tag == "scale":
            if "value" in child.attrs:
                v = parse_numbers(child, child.attrs["value"], "value", (1, 3))
                v = np.repeat(v, 3) if v.size == 1 else v
            else:
                v = np.array([parse_float(child, k) if k in child.attrs else 1.0 for k in "xyz"])
            op[:3, :3] = np.diag(v)
        elif child.tag == "matrix":
            v = parse_numbers(child, child.require("value"), "value", (9, 16))
            if v.size == 9:
                op[:3, :3] = v.reshape(3, 3)
            else:
                op = v.reshape(4, 4)
                if not np.allclose(op[3], [0.0, 0.0, 0.0, 1.0]):
                    raise child.error("a projective matrix (last row not 0 0 0 1) is not supported")
        elif child.tag == "lookat":
            origin = parse_numbers(child, child.require("origin"), "origin", 3)
            target = parse_numbers(child, child.require("target"), "target", 3)
            up = parse_numbers(child, child.attrs.get("up", "0, 1, 0"), "up", 3)
            op = look_at_matrix(origin, target, up, child)
        else:
            raise child.error(f"not a transform operation; supported: {', '.join(TRANSFORM_TAGS)}")
        m = op @ m
    return m

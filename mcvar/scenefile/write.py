"""A Mitsuba 3 scene dictionary written as Mitsuba 3 XML (layer 3.5).

:func:`write_xml` is the generic half of :func:`mcvar.scene.save_scene`: the
dictionary :func:`mcvar.interop.mitsuba.to_mitsuba` builds for
``mi.load_dict`` (the format of Mitsuba's "Dictionary" docs) serialised as the
XML that ``mi.load_file`` and :func:`mcvar.scene.load_scene` read. One mapping
from Scene to Mitsuba (the exporter's); this module only spells it.

Values: ``bool`` -> ``<boolean>``, ``int`` -> ``<integer>``, ``float`` ->
``<float>`` (``repr``: the shortest text that reads back to the same
double), ``str`` -> ``<string>``, three numbers -> ``<point>``,
``{'type': 'rgb'|'spectrum', 'value': ...}`` -> ``<rgb>``/``<spectrum>``,
``{'type': 'ref', 'id': ...}`` -> ``<ref>``, a 4x4 matrix (or anything with a
``matrix`` attribute, such as ``mi.ScalarTransform4f``) -> ``<transform>``
with one ``<matrix>``, :class:`LookAt` and :class:`Rotate` -> their own
elements; any other dict with a ``type`` is a nested plugin, whose element
(``bsdf``, ``shape``, ...) comes from :data:`PLUGIN_TAG`.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ["write_xml", "LookAt", "Rotate", "PLUGIN_TAG"]

#: The XML element of each Mitsuba plugin type this serialiser writes.
PLUGIN_TAG = {
    **{t: "integrator" for t in ("path", "direct", "ptracer", "volpath", "aov", "prb")},
    "perspective": "sensor", "thinlens": "sensor", "orthographic": "sensor",
    "hdrfilm": "film",
    **{t: "rfilter" for t in ("box", "gaussian", "tent", "mitchell", "catmullrom", "lanczos")},
    **{t: "sampler" for t in ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")},
    **{t: "shape" for t in ("ply", "obj", "serialized", "sphere", "rectangle", "cube", "disk", "cylinder")},
    **{t: "bsdf" for t in ("diffuse", "twosided", "conductor", "roughconductor", "dielectric",
                           "roughdielectric", "thindielectric", "plastic", "roughplastic", "principled")},
    **{t: "emitter" for t in ("area", "point", "constant", "envmap", "spot", "directional")},
    **{t: "texture" for t in ("checkerboard", "bitmap")},
}


@dataclass(frozen=True)
class LookAt:
    """A ``<lookat origin target up>`` transform (Mitsuba's ``ScalarTransform4f().look_at``)."""

    origin: tuple
    target: tuple
    up: tuple


@dataclass(frozen=True)
class Rotate:
    """A ``<rotate>`` about ``axis`` by ``angle`` degrees."""

    axis: tuple
    angle: float


def _num(x) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"cannot write a non-finite number ({x}) into a scene file")
    return repr(x)


def _vec(v) -> str:
    return ", ".join(_num(x) for x in v)


def _attr(key, value) -> str:
    return f" {key}={quoteattr(str(value))}"


def _transform(name, value, pad) -> list[str]:
    head = f"{pad}<transform{_attr('name', name)}>"
    if isinstance(value, LookAt):
        body = (f"{pad}    <lookat{_attr('origin', _vec(value.origin))}{_attr('target', _vec(value.target))}"
                f"{_attr('up', _vec(value.up))}/>")
    elif isinstance(value, Rotate):
        axis = "".join(_attr(k, _num(a)) for k, a in zip("xyz", value.axis))
        body = f"{pad}    <rotate{axis}{_attr('angle', _num(value.angle))}/>"
    else:
        m = np.asarray(getattr(value, "matrix", value), dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"{name}: a transform must be a 4x4 matrix; got shape {m.shape}")
        body = f"{pad}    <matrix{_attr('value', ' '.join(_num(x) for x in m.reshape(-1)))}/>"
    return [head, body, f"{pad}</transform>"]


def _is_transform(value) -> bool:
    if isinstance(value, (LookAt, Rotate)) or hasattr(value, "matrix"):
        return True
    return isinstance(value, np.ndarray) and value.shape == (4, 4)


def _property(name, value, pad, where) -> list[str]:
    if isinstance(value, dict):
        kind = value.get("type")
        if kind in ("rgb", "spectrum"):
            v = value.get("value")
            text = _num(v) if isinstance(v, numbers.Real) else _vec(v)
            return [f"{pad}<{kind}{_attr('name', name)}{_attr('value', text)}/>"]
        if kind == "ref":
            return [f"{pad}<ref{_attr('id', value['id'])}{_attr('name', name)}/>"]
        return _plugin(value, pad, name=name, where=f"{where}.{name}")
    if _is_transform(value):
        return _transform(name, value, pad)
    if isinstance(value, (bool, np.bool_)):
        return [f"{pad}<boolean{_attr('name', name)}{_attr('value', 'true' if value else 'false')}/>"]
    if isinstance(value, numbers.Integral):
        return [f"{pad}<integer{_attr('name', name)}{_attr('value', int(value))}/>"]
    if isinstance(value, numbers.Real):
        return [f"{pad}<float{_attr('name', name)}{_attr('value', _num(value))}/>"]
    if isinstance(value, str):
        return [f"{pad}<string{_attr('name', name)}{_attr('value', value)}/>"]
    arr = np.asarray(value)
    if arr.shape == (3,) and arr.dtype.kind in "fiu":
        return [f"{pad}<point{_attr('name', name)}{_attr('value', _vec(arr))}/>"]
    raise ValueError(f"{where}.{name}: cannot write {type(value).__name__} {value!r} as a Mitsuba property")


def _plugin(d, pad, *, name=None, ident=None, where="scene") -> list[str]:
    kind = d.get("type")
    if kind not in PLUGIN_TAG:
        raise ValueError(f"{where}: plugin type {kind!r} has no XML element known to mcvar.scenefile.write "
                         f"(known: {', '.join(sorted(PLUGIN_TAG))})")
    tag = PLUGIN_TAG[kind]
    attrs = _attr("type", kind)
    if ident is not None:
        attrs += _attr("id", ident)
    elif name is not None and name != tag:
        attrs += _attr("name", name)
    body = []
    for key, value in d.items():
        if key == "type":
            continue
        body += _property(key, value, pad + "    ", where)
    if not body:
        return [f"{pad}<{tag}{attrs}/>"]
    return [f"{pad}<{tag}{attrs}>"] + body + [f"{pad}</{tag}>"]


def write_xml(scene_dict: dict, *, comments=()) -> str:
    """The Mitsuba 3 XML text of a scene dictionary (``{'type': 'scene', ...}``).

    Top-level objects get their key as ``id`` (so ``{'type': 'ref', 'id':
    key}`` finds them, as in ``mi.load_dict``); nested ones their key as
    ``name``. ``comments`` are written as XML comments after the root tag.

    Examples
    --------
    >>> print(write_xml({"type": "scene", "integrator": {"type": "path", "max_depth": 3}}))
    <?xml version="1.0" encoding="utf-8"?>
    <scene version="3.0.0">
        <integrator type="path" id="integrator">
            <integer name="max_depth" value="3"/>
        </integrator>
    </scene>
    <BLANKLINE>
    """
    if not isinstance(scene_dict, dict) or scene_dict.get("type") != "scene":
        raise ValueError("scene_dict must be a Mitsuba scene dictionary with type 'scene'")
    lines = ['<?xml version="1.0" encoding="utf-8"?>', '<scene version="3.0.0">']
    for text in comments:
        if "--" in text:
            raise ValueError(f"an XML comment cannot contain '--': {text!r}")
        lines.append(f"    <!-- {text} -->")
    for key, value in scene_dict.items():
        if key == "type":
            continue
        if not isinstance(value, dict) or "type" not in value:
            raise ValueError(f"scene.{key}: a top-level entry must be a plugin dictionary with a 'type'")
        lines += _plugin(value, "    ", ident=key, where=f"scene.{key}")
    lines.append("</scene>")
    return "\n".join(lines) + "\n"

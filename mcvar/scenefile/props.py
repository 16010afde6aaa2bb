"""The properties of one Mitsuba plugin element, each read once (layer 3.5).

:class:`Props` gathers the named properties (``<float>``, ``<rgb>``,
``<transform>`` ...), the nested plugins and the resolved ``<ref>`` of an
element; a plugin reads what it knows with :meth:`Props.get`, and
:meth:`Props.done` raises for anything left, naming it and its line (never a
silent omission). :data:`IOR` is Mitsuba's table of named indices of
refraction.
"""
from __future__ import annotations

import numpy as np

from .xml import PLUGIN_TAGS, PROPERTY_TAGS, Node, parse_float, parse_numbers, parse_transform, parse_vector

__all__ = ["Props", "IOR", "read_ior"]

#: Mitsuba 3's named indices of refraction (its ``ior.h`` table).
IOR = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}

# properties read past on purpose: they do not change the image mcvar computes
_IGNORED = {
    "film": {"pixel_format", "component_format", "file_format", "banner", "high_quality_edges",
             "sample_border"},
    "sensor": {"near_clip", "far_clip", "shutter_open", "shutter_close", "focus_distance"},
    "sampler": {"seed", "jitter", "scramble_type", "dimension"},
    "bsdf": set(),
    "emitter": {"sampling_weight"},
    "integrator": set(),
    "shape": set(),
    "rfilter": set(),
    "texture": set(),
}


class Props:
    """The properties and nested objects of one plugin element, read once each.

    ``get`` records every name it is asked for; :meth:`done` raises for
    whatever the file gave that the plugin did not read, listing what it
    reads (never a silent omission).
    """

    def __init__(self, node: Node, builder):
        self.node = node
        self.values: dict[str, tuple[str, object, Node]] = {}
        self.objects: list[Node] = []
        self.asked: list[str] = []
        for child in node.children:
            if child.tag == "default" and node.tag == "scene":
                continue
            if child.tag == "ref":
                target = builder.resolve(child)
                if child.name:
                    self.values[child.name] = ("object", target, child)
                else:
                    self.objects.append(target)
            elif child.tag in PLUGIN_TAGS:
                if child.name:
                    self.values[child.name] = ("object", child, child)
                else:
                    self.objects.append(child)
            elif child.tag in PROPERTY_TAGS:
                name = child.require("name")
                if name in self.values:
                    raise child.error(f"property {name!r} is given twice")
                self.values[name] = (child.tag, _value(child), child)
            else:
                raise child.error(f"<{child.tag}> is not supported inside <{node.tag}>; supported: "
                                  f"{', '.join(PROPERTY_TAGS + PLUGIN_TAGS)}, ref")

    def get(self, name, kinds, default=None):
        self.asked.append(name)
        if name not in self.values:
            return default
        kind, value, child = self.values.pop(name)
        if kind == "integer" and "float" in kinds:
            return float(value)                       # as Mitsuba: an integer where a float is read
        if kind not in kinds:
            raise child.error(f"property {name!r} must be given as {' or '.join('<' + k + '>' for k in kinds)}")
        return value

    def child(self, name):
        """The element that gave property ``name`` (for messages), else the plugin's."""
        return self.values[name][2] if name in self.values else self.node

    def color(self, name, default):
        self.asked.append(name)
        if name not in self.values:
            return None if default is None else np.broadcast_to(np.asarray(default, dtype=np.float64), 3).copy()
        kind, value, child = self.values.pop(name)
        if kind in ("rgb", "spectrum", "float"):
            return np.broadcast_to(np.asarray(value, dtype=np.float64), 3).copy()
        if kind == "object" and value.tag == "texture":
            return value
        raise child.error(f"{name!r} must be <rgb>, <spectrum value=...>, <float> or a <texture>")

    def objects_of(self, tag):
        found = [o for o in self.objects if o.tag == tag]
        self.objects = [o for o in self.objects if o.tag != tag]
        return found

    def done(self):
        ignored = _IGNORED.get(self.node.tag, set())
        for name, (kind, value, child) in self.values.items():
            if name in ignored:
                continue
            raise child.error(f"property {name!r} is not supported by <{self.node.tag} type="
                              f"{self.node.type!r}>; it reads: {', '.join(self.asked) or 'nothing'}")
        for obj in self.objects:
            raise obj.error(f"a nested <{obj.tag}> is not supported inside <{self.node.tag} type="
                            f"{self.node.type!r}>")


def _value(child: Node):
    tag = child.tag
    if tag == "float":
        return parse_float(child)
    if tag == "integer":
        text = child.require("value")
        try:
            return int(text)
        except ValueError:
            raise child.error(f"value={text!r} is not an integer") from None
    if tag == "boolean":
        text = child.require("value").strip().lower()
        if text not in ("true", "false"):
            raise child.error(f"value={text!r} must be true or false")
        return text == "true"
    if tag == "string":
        return child.require("value")
    if tag == "rgb":
        v = parse_numbers(child, child.require("value"), "value", (1, 3))
        return np.repeat(v, 3) if v.size == 1 else v
    if tag == "spectrum":
        if "filename" in child.attrs:
            raise child.error("spectra from files are not supported: give <rgb> or a constant <spectrum value=...>")
        text = child.require("value")
        if ":" in text:
            raise child.error("sampled spectra (wavelength:value pairs) are not supported: give <rgb> "
                              "or a constant <spectrum value=...>")
        return float(parse_numbers(child, text, "value", 1)[0])
    if tag in ("point", "vector"):
        return parse_vector(child)
    if tag == "transform":
        return parse_transform(child)
    raise child.error(f"unknown property element <{tag}>")  # pragma: no cover (PROPERTY_TAGS)


def read_ior(props: Props, name, default):
    value = props.get(name, ("float", "string"), default)
    if isinstance(value, str):
        key = value.strip().lower()
        if key not in IOR:
            raise props.node.error(f"{name}={value!r} is not a known index of refraction; known: "
                                   f"{', '.join(IOR)} (or a number)")
        return IOR[key]
    if not value > 0:
        raise props.node.error(f"{name} must be > 0; got {value}")
    return float(value)

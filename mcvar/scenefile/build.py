"""A Mitsuba 3 plugin tree turned into the fields of a :class:`mcvar.scene.Scene` (layer 3.5).

The second half of :func:`mcvar.scene.load_scene` for files:
:func:`scene_fields` walks the :class:`~mcvar.scenefile.xml.Node` tree of
:func:`~mcvar.scenefile.xml.parse_xml` and returns plain data (arrays,
:mod:`mcvar.bsdf` materials, an :class:`mcvar.envmap.EnvironmentMap`, the
camera's ``position, look_at, up, fov_deg``); ``load_scene`` builds the
``Scene`` and its ``Camera`` from them. docs/scene-files.md has the
supported subset as a table; every element or property outside it is a
:class:`~mcvar.scenefile.xml.SceneFileError` naming its line and what is
supported.

How Mitsuba's objects become mcvar's (each a documented choice):

* **Shapes** become triangles (``rectangle``, ``cube``, ``disk``, ``obj``,
  ``ply``; :mod:`mcvar.scenefile.mesh`) or analytic spheres. Meshes get a
  triangle group of their own per 64 triangles (a median split, so the
  tracer's bounding-box culling works like a one-level hierarchy).
* **Area emitters** give every triangle of their shape its radiance (one
  sided, towards the front normal). Each pair of consecutive triangles that
  forms a parallelogram (a ``rectangle``, each face of a ``cube``, the quads
  of a mesh) also becomes one of mcvar's parallelogram lights, which next
  event estimation samples; the other emitting triangles and emitting
  spheres are reached by BSDF sampling (and are origins of light subpaths):
  unbiased either way, only the variance differs.
* **BSDFs**: mcvar's reflection models are two-sided (the shading normal is
  turned towards the viewer), Mitsuba's are black from behind unless wrapped
  in ``twosided``: the same image wherever no back face is seen.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..bsdf import Conductor, Glass, Lambertian, Mirror, Plastic
from ..envmap import EnvironmentMap, constant
from ..images import read_image
from . import mesh as _mesh
from .lights import as_parallelogram, envmap_to_mcvar, unrefine
from .props import IOR, Props, read_ior
from .xml import PLUGIN_TAGS, PROPERTY_TAGS, Node, SceneFileError

__all__ = ["scene_fields", "SUPPORTED", "IOR"]

#: Plugin types read, per element (docs/scene-files.md's table).
SUPPORTED = {
    "integrator": ("path",),
    "sensor": ("perspective",),
    "film": ("hdrfilm",),
    "rfilter": ("box",),
    "sampler": ("independent", "stratified", "multijitter", "orthogonal", "ldsampler"),
    "shape": ("rectangle", "cube", "disk", "sphere", "obj", "ply"),
    "bsdf": ("diffuse", "twosided", "conductor", "dielectric", "plastic"),
    "emitter": ("area", "point", "constant", "envmap"),
    "texture": ("checkerboard (as an area emitter's radiance)",),
}

#: Mitsuba BSDFs whose mcvar namesake is a different model (measured against
#: Mitsuba's ``BSDF.eval`` in tests/test_scenefile.py), so a file using them would
#: render a different image: refused, with the reason.
_NOT_THE_SAME = {
    "roughconductor": "Mitsuba's rough conductor masks with the separable Smith G1(wo) G1(wi), mcvar's "
                      "Conductor with the height-correlated 1 / (1 + Lambda(wo) + Lambda(wi)) (3% apart at "
                      "alpha 0.3); use a smooth <bsdf type=\"conductor\">",
    "roughplastic": "Mitsuba's rough plastic couples the base through the coat with a 1 / eta^2 factor and "
                    "its own albedo table, mcvar's Plastic(alpha > 0) with Kelemen and Szirmay-Kalos' "
                    "coupling; use <bsdf type=\"plastic\"> (smooth, nonlinear=true)",
    "roughdielectric": "mcvar has no rough dielectric",
    "thindielectric": "mcvar has no thin dielectric",
}

#: Triangles per culling group of a mesh.
GROUP_SIZE = 64

def _apply(m, points):
    return points @ m[:3, :3].T + m[:3, 3]


class _Builder:
    def __init__(self, root: Node):
        self.root = root
        self.ids: dict[str, Node] = {}
        self._collect_ids(root)
        self._building: list[str] = []
        self.triangles, self.tri_material, self.tri_emission, self.tri_light, self.tri_group = [], [], [], [], []
        self.spheres, self.sphere_material, self.sphere_emission = [], [], []
        self.lights: list[tuple] = []
        self.points: list[tuple] = []
        self.materials, self.material_names, self._material_of = [], [], {}
        self.environment = None
        self.checker = None        # the period of an emitting checkerboard
        self.plain_emitters = []   # area emitters of constant radiance (mcvar's checker would pattern them)
        self.camera = None
        self.defaults = {}
        self.n_groups = 0
        self.inward = []           # (sphere index, node) of spheres emitting inwards (flip_normals)
        self.two_sided_spheres = set()

    # ids and references ------------------------------------------------
    def _collect_ids(self, node):
        for child in node.children:
            if child.tag in PLUGIN_TAGS and "id" in child.attrs:
                key = child.attrs["id"]
                if key in self.ids:
                    raise child.error(f"id {key!r} is already used on line {self.ids[key].line}")
                self.ids[key] = child
            self._collect_ids(child)

    def resolve(self, ref: Node) -> Node:
        key = ref.require("id")
        if key not in self.ids:
            raise ref.error(f"<ref id={key!r}> names no object (ids: {', '.join(self.ids) or 'none'})")
        if key in self._building:
            chain = " -> ".join(self._building[self._building.index(key):] + [key])
            raise ref.error(f"cyclic <ref>: {chain}")
        return self.ids[key]

    def props(self, node: Node) -> Props:
        key = node.attrs.get("id")
        if key is not None:
            self._building.append(key)
        try:
            return Props(node, self)
        finally:
            if key is not None:
                self._building.pop()

    def _check_type(self, node: Node):
        kind = node.type
        if kind is None:
            raise node.error("missing attribute 'type'")
        if node.tag == "bsdf" and kind in _NOT_THE_SAME:
            raise node.error(f"<bsdf type={kind!r}> is not supported: {_NOT_THE_SAME[kind]}")
        if kind not in SUPPORTED[node.tag] and not (node.tag == "texture"):
            raise node.error(f"<{node.tag} type={kind!r}> is not supported; supported: "
                             f"{', '.join(SUPPORTED[node.tag])}")

    # the scene ------------------------------------------------------------
    def build(self):
        scene_props = self.props(self.root)
        # materials in the order the file declares them at the top level (used or not), then
        # those nested in shapes: a scene written by save_scene keeps its material table
        objects = scene_props.objects + [v for kind, v, _ in scene_props.values.values() if kind == "object"]
        for node in objects:
            if node.tag == "bsdf" and "id" in node.attrs and self._checker_reflectance(node) is None:
                self.material(node)
        seen_integrator = None
        for node in objects:
            self._check_type(node)
            if node.tag == "integrator":
                if seen_integrator is not None:
                    raise node.error(f"a second <integrator> (the first is on line {seen_integrator.line})")
                seen_integrator = node
                self.integrator(node)
            elif node.tag == "sensor":
                if self.camera is not None:
                    raise node.error("mcvar renders one sensor; this is the second")
                self.sensor(node)
            elif node.tag == "shape":
                self.shape(node)
            elif node.tag == "emitter":
                self.emitter(node, shape=None)
            elif node.tag in ("bsdf", "texture"):
                if "id" not in node.attrs:
                    raise node.error(f"a top-level <{node.tag}> needs an id (it is used through <ref>)")
            else:
                raise node.error(f"<{node.tag}> is not supported at the top level; supported: integrator, "
                                 "sensor, shape, emitter, bsdf, texture, default")
        for name, (kind, value, child) in scene_props.values.items():
            if kind == "object":
                continue
            raise child.error("a property directly inside <scene> is not supported")
        for child in self.root.children:
            if child.tag not in PLUGIN_TAGS + PROPERTY_TAGS + ("default", "ref"):
                raise child.error(f"<{child.tag}> is not supported; supported at the top level: "
                                  "integrator, sensor, shape, emitter, bsdf, texture, default")
        if self.camera is None:
            raise SceneFileError(f"{self.root.source}: the scene has no <sensor type=\"perspective\">")
        if self.checker is not None and self.plain_emitters:
            raise self.plain_emitters[0].error(
                "mcvar's checker patterns every emitter of a scene: a checkerboard emitter cannot sit beside "
                "an emitter of constant radiance")
        self._check_inward_spheres()
        return self.fields()

    def integrator(self, node):
        p = self.props(node)
        depth = p.get("max_depth", ("integer",), -1)
        rr = p.get("rr_depth", ("integer",), None)
        hide = p.get("hide_emitters", ("boolean",), False)
        p.done()
        if hide:
            raise node.error("hide_emitters=true is not supported (mcvar's camera sees emitters)")
        if depth == 0 or depth < -1:
            raise node.error(f"max_depth must be -1 (no limit) or >= 1; got {depth}")
        self.defaults["max_depth"] = None if depth == -1 else int(depth)
        if rr is not None:
            if rr < 1:
                raise node.error(f"rr_depth must be >= 1; got {rr}")
            self.defaults["rr_depth"] = int(rr)

    def sensor(self, node):
        p = self.props(node)
        fov = p.get("fov", ("float",), None)
        axis = p.get("fov_axis", ("string",), "x")
        to_world = p.get("to_world", ("transform",), np.eye(4))
        for name in ("focal_length", "principal_point_offset_x", "principal_point_offset_y"):
            if name in p.values:
                raise p.child(name).error(f"{name} is not supported: give fov (degrees) and fov_axis")
        films = p.objects_of("film") + ([p.get("film", ("object",))] if "film" in p.values else [])
        samplers = p.objects_of("sampler") + ([p.get("sampler", ("object",))] if "sampler" in p.values else [])
        p.done()
        width, height = 768, 576                          # Mitsuba's hdrfilm defaults
        if films:
            width, height = self.film(films[0])
        if samplers:
            self.sampler(samplers[0])
        if fov is None:
            raise node.error("missing property 'fov' (<float name=\"fov\" value=\"...\"/>, degrees)")
        if not 0.0 < fov < 180.0:
            raise p.child("fov").error(f"fov must lie in (0, 180) degrees; got {fov}")
        t = math.tan(math.radians(fov) / 2.0)
        aspect = width / height
        axes = {"x": 1.0, "y": aspect, "diagonal": width / math.hypot(width, height),
                "smaller": max(aspect, 1.0), "larger": min(aspect, 1.0)}
        if axis not in axes:
            raise node.error(f"fov_axis={axis!r} is not supported; supported: {', '.join(axes)}")
        if axis == "diagonal":
            t *= axes["diagonal"]
        else:
            t *= axes[axis]
        factor = axes["diagonal"] if axis == "diagonal" else axes[axis]
        fov_x = fov if factor == 1.0 else math.degrees(2.0 * math.atan(t))   # exact when already horizontal
        m = to_world[:3, :3]
        cols = [m[:, i] for i in range(3)]
        norms = [np.linalg.norm(c) for c in cols]
        ortho = max(abs(cols[i] @ cols[j]) for i, j in ((0, 1), (0, 2), (1, 2))) <= 1e-6 * max(norms) ** 2
        if not (min(norms) > 0 and ortho and max(norms) - min(norms) <= 1e-6 * max(norms)
                and np.linalg.det(m) > 0):
            raise node.error("the sensor's to_world must be a rotation (times a uniform scale) and a "
                             "translation: mcvar's pinhole cannot mirror or shear the image")
        position = to_world[:3, 3]
        forward = cols[2] / norms[2]
        self.camera = dict(position=position, look_at=position + forward, up=cols[1] / norms[1],
                           fov_deg=fov_x)
        self.defaults["res"] = (int(width), int(height))

    def film(self, node):
        self._check_type(node)
        p = self.props(node)
        width = p.get("width", ("integer",), 768)
        height = p.get("height", ("integer",), 576)
        for name in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"):
            if name in p.values:
                raise p.child(name).error(f"{name} is not supported (mcvar renders the whole film)")
        filters = p.objects_of("rfilter") + ([p.get("rfilter", ("object",))] if "rfilter" in p.values else [])
        p.done()
        if not (width >= 1 and height >= 1):
            raise node.error(f"width and height must be >= 1; got {width} x {height}")
        if filters:
            f = filters[0]
            if f.type != "box":
                raise f.error(f"<rfilter type={f.type!r}> is not supported: mcvar's pixels are box "
                              "filtered (each pixel the mean over its square); use <rfilter type=\"box\"/>")
            self.props(f).done()
        else:
            warnings.warn(f"{node.where()}: no <rfilter>: Mitsuba's default is a Gaussian filter, mcvar's "
                          "pixels are box filtered (add <rfilter type=\"box\"/> for the same image in both)",
                          UserWarning, stacklevel=6)
        return width, height

    def sampler(self, node):
        self._check_type(node)
        p = self.props(node)
        spp = p.get("sample_count", ("integer",), 4)
        p.done()
        if not spp >= 1:
            raise node.error(f"sample_count must be >= 1; got {spp}")
        self.defaults["spp"] = int(spp)

    # materials ----------------------------------------------------------
    def material(self, node, emitting=False):
        """Index into ``materials`` of a <bsdf> node (the same node gives the same index).

        A shape without a <bsdf> gets Mitsuba's default: ``diffuse`` of
        reflectance 0.5, or 0 (black) when the shape is an area emitter.
        """
        if node is None:
            key = ("default", emitting)
            if key not in self._material_of:
                self._material_of[key] = self._add_material(Lambertian(0.0 if emitting else 0.5),
                                                            "default-black" if emitting else "default-diffuse")
            return self._material_of[key]
        key = id(node)
        if key not in self._material_of:
            self._check_type(node)
            bsdf = self.bsdf(node)
            name = node.attrs.get("id") or f"{node.type}-{node.line}"
            self._material_of[key] = self._add_material(bsdf, name)
        return self._material_of[key]

    def _add_material(self, bsdf, name):
        self.materials.append(bsdf)
        self.material_names.append(name)
        return len(self.materials) - 1

    def bsdf(self, node):
        key = node.attrs.get("id")
        if key is not None:
            self._building.append(key)
        try:
            return self._bsdf(node)
        finally:
            if key is not None:
                self._building.pop()

    def _bsdf(self, node):
        self._check_type(node)
        p = self.props(node)
        kind = node.type
        try:
            if kind == "diffuse":
                rho = p.color("reflectance", 0.5)
                p.done()
                if isinstance(rho, Node):
                    raise self._texture_error(rho, "diffuse reflectance")
                return Lambertian(rho)
            if kind == "twosided":
                inner = p.objects_of("bsdf") + [v for k, (kk, v, c) in list(p.values.items())
                                                if kk == "object" and v.tag == "bsdf"]
                for k in [k for k, (kk, v, c) in p.values.items() if kk == "object" and v.tag == "bsdf"]:
                    p.values.pop(k)
                p.done()
                if len(inner) != 1:
                    raise node.error(f"twosided needs exactly one nested <bsdf> (mcvar has no different "
                                     f"back side); got {len(inner)}")
                return self.bsdf(inner[0])
            if kind == "conductor":
                return self._conductor(node, p)
            if kind == "dielectric":
                eta = read_ior(p, "int_ior", IOR["bk7"]) / read_ior(p, "ext_ior", IOR["air"])
                r = p.color("specular_reflectance", 1.0)
                t = p.color("specular_transmittance", 1.0)
                p.done()
                for v, name in ((r, "specular_reflectance"), (t, "specular_transmittance")):
                    if isinstance(v, Node):
                        raise self._texture_error(v, name)
                return Glass(eta, reflectance=r, transmittance=t)
            if kind == "plastic":
                rho = p.color("diffuse_reflectance", 0.5)
                spec = p.color("specular_reflectance", 1.0)
                eta = read_ior(p, "int_ior", IOR["polypropylene"]) / read_ior(p, "ext_ior", IOR["air"])
                nonlinear = p.get("nonlinear", ("boolean",), False)
                p.done()
                for v, name in ((rho, "diffuse_reflectance"), (spec, "specular_reflectance")):
                    if isinstance(v, Node):
                        raise self._texture_error(v, name)
                if not nonlinear:
                    raise node.error("mcvar's Plastic sums the internal bounces (Mitsuba's nonlinear=true); "
                                     "add <boolean name=\"nonlinear\" value=\"true\"/> to use it")
                return Plastic(rho, eta=eta, specular=spec)
        except SceneFileError:
            raise
        except (ValueError, TypeError) as exc:
            raise node.error(str(exc)) from None
        raise node.error(f"<bsdf type={kind!r}> is not supported")  # pragma: no cover

    def _conductor(self, node, p, rough=False):
        """Mitsuba's smooth ``conductor``: ``material`` ``none`` (a mirror, times
        ``specular_reflectance``), ``Cu`` or ``Au`` (mcvar's presets), or ``eta`` and ``k`` as <rgb>."""
        material = p.get("material", ("string",), None)
        eta = p.color("eta", None)
        k = p.color("k", None)
        spec = p.color("specular_reflectance", 1.0)
        p.done()
        if isinstance(spec, Node):
            raise self._texture_error(spec, "specular_reflectance")
        if isinstance(eta, Node) or isinstance(k, Node):
            raise node.error("textured eta or k is not supported")
        if (eta is None) != (k is None):
            raise node.error("give both eta and k, or a material name")
        if eta is not None and material is not None:
            raise node.error("give eta and k, or material, not both")
        if eta is None and material is None:
            material = "none"                         # Mitsuba 3's default conductor: a perfect mirror
        if material == "none":
            return Mirror(spec)
        if not np.allclose(spec, 1.0):
            raise node.error("specular_reflectance != 1 on a conductor is not supported (only with "
                             "material none, the mirror)")
        if material is not None:
            raise node.error(f"conductor material {material!r} is not supported: Mitsuba integrates its "
                             "measured spectra over its RGB curves, mcvar's presets (copper, gold) sample them "
                             "at three wavelengths (normal-incidence blue reflectance of Au: 0.32 vs 0.41); "
                             "give material none (a mirror) or the index as <rgb name=\"eta\"> and "
                             "<rgb name=\"k\">, which both engines use alike")
        return Conductor(eta, k)

    def _texture_error(self, tex: Node, what):
        if tex.type == "bitmap":
            return tex.error(f"a bitmap texture as {what} is not supported: mcvar's materials hold one "
                             "constant albedo per primitive, and a per-hit texture lookup would need the "
                             "integrator loops (mcvar.integrators) to evaluate it")
        if tex.type == "checkerboard":
            return tex.error(f"a checkerboard texture as {what} is not supported: it is read as a diffuse "
                             "reflectance on a rectangle or a PLY mesh with u, v (cut into its squares), and as "
                             "an area emitter's radiance (mcvar's Scene.checker_period)")
        return tex.error(f"<texture type={tex.type!r}> is not supported; supported: checkerboard (as an "
                         "area emitter's radiance)")

    # shapes ---------------------------------------------------------------
    def shape(self, node):
        p = self.props(node)
        kind = node.type
        to_world = p.get("to_world", ("transform",), np.eye(4))
        flip = p.get("flip_normals", ("boolean",), False)
        face_normals = p.get("face_normals", ("boolean",), False)
        bsdfs = p.objects_of("bsdf") + [p.get(k, ("object",)) for k in
                                         [k for k, (kk, v, c) in p.values.items() if kk == "object" and v.tag == "bsdf"]]
        emitters = p.objects_of("emitter") + [p.get(k, ("object",)) for k in
                                              [k for k, (kk, v, c) in p.values.items()
                                               if kk == "object" and v.tag == "emitter"]]
        if len(bsdfs) > 1:
            raise bsdfs[1].error("a shape has one <bsdf>")
        if len(emitters) > 1:
            raise emitters[1].error("a shape has one <emitter>")
        if np.linalg.matrix_rank(to_world[:3, :3]) < 3:
            raise node.error("to_world is singular (a zero scale?)")
        if kind == "sphere":
            center = p.get("center", ("point",), np.zeros(3))
            radius = p.get("radius", ("float",), 1.0)
            p.done()
            if not radius > 0:
                raise node.error(f"radius must be > 0; got {radius}")
            m = to_world[:3, :3]
            scales = np.linalg.svd(m, compute_uv=False)
            if scales.max() - scales.min() > 1e-9 * scales.max():
                raise node.error("a sphere's to_world must scale uniformly (mcvar's spheres are round)")
            world_center = _apply(to_world, center[None])[0]
            world_radius = radius * scales[0]
            mat = self.material(bsdfs[0] if bsdfs else None, emitting=bool(emitters))
            emission = np.zeros(3)
            if emitters:
                emission = self._area_radiance(emitters[0], checker_shape=None)
                if flip and np.any(emission > 0):
                    self.inward.append((len(self.spheres), node))
            self.spheres.append((world_center, world_radius))
            self.sphere_material.append(mat)
            self.sphere_emission.append(emission)
            return
        if kind in ("rectangle", "cube", "disk"):
            p.done()
            local = {"rectangle": _mesh.rectangle, "cube": _mesh.cube, "disk": _mesh.disk}[kind]()
            # Mitsuba's rectangle: (u, v) = ((x + 1) / 2, (y + 1) / 2) of the local point
            local_uv = 0.5 * (local[..., :2] + 1.0) if kind == "rectangle" else None
        elif kind in ("obj", "ply"):
            where = p.child("filename")
            filename = p.get("filename", ("string",), None)
            p.done()
            if filename is None:
                raise node.error("missing property 'filename' (<string name=\"filename\" value=\"...\"/>)")
            path = Path(filename)
            if not path.is_absolute():
                path = node.directory / path
            if not path.is_file():
                raise where.error(f"mesh file {str(path)!r} does not exist")
            if path.suffix.lower() != "." + kind:
                raise node.error(f"<shape type={kind!r}> needs a .{kind} file; got {path.name!r}")
            try:
                if kind == "ply":
                    local, local_uv = _mesh.read_ply(path, uv=True)
                else:
                    local, local_uv = _mesh.read_obj(path), None
            except _mesh.MeshError as exc:
                raise node.error(str(exc)) from None
            if not face_normals:
                warnings.warn(f"{node.where()}: mcvar shades meshes with face normals; Mitsuba interpolates "
                              "vertex normals unless <boolean name=\"face_normals\" value=\"true\"/> (the "
                              "images differ on curved meshes)", UserWarning, stacklevel=5)
        else:
            raise node.error(f"<shape type={kind!r}> is not supported; supported: "
                             f"{', '.join(SUPPORTED['shape'])}")
        tris = _apply(to_world, local.reshape(-1, 3)).reshape(-1, 3, 3)
        if kind in ("rectangle", "disk") and np.linalg.det(to_world[:3, :3]) < 0:
            # Mitsuba's analytic shapes keep the normal to_world gives (0, 0, 1): a mirroring
            # transform must not turn them inside out
            tris = tris[:, [0, 2, 1]]
        if flip:
            tris = tris[:, [0, 2, 1]]
        area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        keep = area2 > 1e-12 * max(float(np.max(area2, initial=0.0)), 1e-300)
        if not np.any(keep):
            raise node.error("the shape has no triangle of positive area")
        tris = tris[keep]
        uv_tris = None
        if local_uv is not None:
            uv_tris = local_uv[keep]
            if kind in ("rectangle", "disk") and np.linalg.det(to_world[:3, :3]) < 0:
                uv_tris = uv_tris[:, [0, 2, 1]]
            if flip:
                uv_tris = uv_tris[:, [0, 2, 1]]
        checker = self._checker_reflectance(bsdfs[0]) if bsdfs else None
        if checker is None:
            mat = self.material(bsdfs[0] if bsdfs else None, emitting=bool(emitters))
        else:
            tris, mat = self._checkered(tris, uv_tris, bsdfs[0], *checker)
            uv_tris = None
        n = tris.shape[0]
        emission = np.zeros((n, 3))
        light = np.full(n, -1)
        if emitters:
            radiance = self._area_radiance(emitters[0], checker_shape=(kind, tris, uv_tris))
            emission[:] = radiance
            if np.any(radiance > 0):
                light = self._parallelogram_lights(tris, radiance)
        self.triangles.append(tris)
        self.tri_material.append(np.broadcast_to(np.asarray(mat, dtype=np.int64), (n,)).copy())
        self.tri_emission.append(emission)
        self.tri_light.append(light)
        self.tri_group.append(self._groups(tris) if (kind in ("obj", "ply", "disk") or checker is not None)
                              and n > GROUP_SIZE
                              else np.zeros(n, dtype=np.int64))

    def _check_inward_spheres(self):
        """A sphere that emits inwards (Mitsuba: area emitter and flip_normals) is mcvar's
        two-sided emitting sphere when nothing outside it can see it: the camera, every
        other shape and every point light inside it, and no environment."""
        for k, node in self.inward:
            c, r = self.spheres[k]
            pts = [np.asarray(self.camera["position"])[None]] + [t.reshape(-1, 3) for t in self.triangles]
            pts += [np.asarray(pt[0])[None] for pt in self.points]
            inside = all(np.all(np.linalg.norm(q - c, axis=1) < r) for q in pts)
            inside &= all(np.linalg.norm(c2 - c) + r2 < r for j, (c2, r2) in enumerate(self.spheres) if j != k)
            if not inside or self.environment is not None:
                raise node.error("a sphere emitting inwards (area emitter with flip_normals) is supported when "
                                 "everything else is inside it (mcvar then emits on both sides); here something "
                                 "outside could see its outside")
            self.two_sided_spheres.add(k)

    def _checker_reflectance(self, node):
        """``(color0, color1, to_uv, texture)`` if ``node`` is a ``diffuse`` (possibly in
        ``twosided``) whose reflectance is a ``checkerboard``; else None."""
        seen = set()
        while node.type == "twosided":
            if id(node) in seen:
                return None                            # material() reports the cycle
            seen.add(id(node))
            p = self.props(node)
            inner = [o for o in p.objects if o.tag == "bsdf"] + [v for kind, v, _ in p.values.values()
                                                                 if kind == "object" and v.tag == "bsdf"]
            if len(inner) != 1:
                return None
            node = inner[0]
        if node.type != "diffuse":
            return None
        p = self.props(node)
        given = p.values.get("reflectance")
        if given is None or given[0] != "object" or given[1].type != "checkerboard":
            return None
        p.get("reflectance", ("object",))
        p.done()
        tex = given[1]
        tp = self.props(tex)
        c0 = tp.color("color0", 0.4)
        c1 = tp.color("color1", 0.2)
        to_uv = tp.get("to_uv", ("transform",), np.eye(4))
        tp.done()
        if isinstance(c0, Node) or isinstance(c1, Node):
            raise tex.error("nested textures in a checkerboard are not supported")
        return c0, c1, to_uv, tex

    def _checkered(self, tris, uv, bsdf_node, c0, c1, to_uv, tex):
        """A diffuse checkerboard as geometry: the shape cut along the squares' edges
        (exact: texture coordinates are linear across each triangle), each piece with the
        Lambertian of its square's colour (Mitsuba: ``color1`` where ``floor(2 u') +
        floor(2 v')`` is odd). Returns the pieces and their material indices."""
        if uv is None:
            raise tex.error("a checkerboard reflectance needs texture coordinates: on a rectangle or a PLY "
                            "mesh with u, v")
        g = 2.0 * (uv @ to_uv[np.ix_([0, 1], [0, 1])].T + to_uv[[0, 1], 3])
        try:
            pieces, square = _mesh.split_by_checker(tris, g)
            key = ("checker", id(bsdf_node))
            if key not in self._material_of:
                name = bsdf_node.attrs.get("id") or f"checkerboard-{tex.line}"
                self._material_of[key] = (self._add_material(Lambertian(c0), f"{name}-color0"),
                                          self._add_material(Lambertian(c1), f"{name}-color1"))
        except ValueError as exc:
            raise tex.error(str(exc)) from None
        m0, m1 = self._material_of[key]
        return pieces, np.where(square.sum(axis=1) % 2 == 1, m1, m0)

    def _groups(self, tris):
        """Culling groups of ~GROUP_SIZE triangles by recursive median splits of the centroids."""
        centroid = tris.mean(axis=1)
        groups = np.zeros(tris.shape[0], dtype=np.int64)
        stack = [np.arange(tris.shape[0])]
        while stack:
            idx = stack.pop()
            if idx.size <= GROUP_SIZE:
                self.n_groups += 1
                groups[idx] = self.n_groups
                continue
            c = centroid[idx]
            axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
            order = idx[np.argsort(c[:, axis], kind="stable")]
            half = order.size // 2
            stack += [order[:half], order[half:]]
        return groups

    def _parallelogram_lights(self, tris, radiance):
        """Lights for consecutive triangle pairs that form a parallelogram; -1 for the others."""
        light = np.full(tris.shape[0], -1)
        k = 0
        while k + 1 < tris.shape[0]:
            quad = as_parallelogram(tris[k], tris[k + 1])
            if quad is None:
                k += 1
                continue
            origin, e1, e2 = quad
            light[k] = light[k + 1] = len(self.lights)
            self.lights.append((origin, e1, e2, radiance))
            k += 2
        return light

    def _area_radiance(self, emitter: Node, checker_shape):
        self._check_type(emitter)
        if emitter.type != "area":
            raise emitter.error(f"an emitter inside a shape must be type 'area'; got {emitter.type!r}")
        p = self.props(emitter)
        radiance = p.color("radiance", 1.0)
        p.done()
        if isinstance(radiance, Node):
            if radiance.type != "checkerboard":
                raise self._texture_error(radiance, "radiance")
            if checker_shape is not None and checker_shape[2] is None and checker_shape[0] in ("rectangle", "ply"):
                raise radiance.error("a checkerboard radiance on a shape whose reflectance is a checkerboard "
                                     "too is not supported")
            if checker_shape is None or checker_shape[2] is None:
                raise radiance.error("a checkerboard radiance is supported on a rectangle or a PLY mesh with "
                                     "texture coordinates (u, v) (mcvar's checker is a pattern in world x, z)")
            return self._checker(radiance, checker_shape[1], checker_shape[2])
        if not np.all(radiance >= 0):
            raise emitter.error(f"radiance must be non-negative; got {radiance.tolist()}")
        if np.any(radiance > 0):
            self.plain_emitters.append(emitter)
        return radiance

    def _checker(self, tex: Node, tris, uv):
        """The radiance of an emitting checkerboard shape, if it is mcvar's checker.

        mcvar's checker (``Scene.checker_period = p``) multiplies emission by
        ``(floor(x / p) + floor(z / p)) mod 2`` of the world hit point.
        Mitsuba 3's paints ``color1`` where ``floor(2 u') + floor(2 v')`` is
        odd and ``color0`` elsewhere (measured with ``Texture.eval``),
        ``(u', v') = to_uv (u, v)``. Texture coordinates are interpolated
        linearly across each triangle, so the two agree when every vertex has
        ``2 (u', v') = G (x, z) + h`` for one ``G`` that is ``+-1 / p`` times
        a permutation, ``h`` integer, and one colour is black: checked here
        on the vertices (a least-squares fit that must be exact), so
        anything else is an error rather than a different picture.
        """
        p = self.props(tex)
        c0 = p.color("color0", 0.4)
        c1 = p.color("color1", 0.2)
        to_uv = p.get("to_uv", ("transform",), np.eye(4))
        p.done()
        if isinstance(c0, Node) or isinstance(c1, Node):
            raise tex.error("nested textures in a checkerboard are not supported")
        # Mitsuba keeps the 2D affine part of to_uv: rows/columns 0, 1 and the translation
        uvp = uv.reshape(-1, 2) @ to_uv[np.ix_([0, 1], [0, 1])].T + to_uv[[0, 1], 3]
        xz = tris.reshape(-1, 3)[:, [0, 2]]
        design = np.column_stack([xz, np.ones(len(xz))])
        coef, *_ = np.linalg.lstsq(design, 2.0 * uvp, rcond=None)
        scale = max(np.abs(2.0 * uvp).max(), 1.0)
        if np.abs(design @ coef - 2.0 * uvp).max() > 1e-6 * scale:
            raise tex.error("the checkerboard's texture coordinates must be an affine function of world x "
                            "and z (mcvar's checker is a pattern in world x and z)")
        g, h = coef[:2].T, coef[2]
        big = np.abs(g).max()
        diag = abs(g[0, 1]) < 1e-9 * big and abs(g[1, 0]) < 1e-9 * big
        anti = abs(g[0, 0]) < 1e-9 * big and abs(g[1, 1]) < 1e-9 * big
        if not (diag or anti):
            raise tex.error("the checkerboard's squares must be aligned with world x and z")
        entries = g[[0, 1], [0, 1]] if diag else g[[0, 1], [1, 0]]
        if abs(abs(entries[0]) - abs(entries[1])) > 1e-9 * big:
            raise tex.error("the checkerboard's squares must be square in world x and z")
        period = 1.0 / abs(entries[0])
        if np.any(np.abs(h - np.round(h)) > 1e-6):
            raise tex.error(f"the checkerboard's squares must start on multiples of their side {period:g} "
                            "in world x and z (mcvar's checker has its corner at the origin)")
        # parity: the integer offsets, plus one per mirrored axis (floor(-s) = -floor(s) - 1)
        shift = int(np.round(h).sum()) + int(np.sum(entries < 0))
        lit, dark = (c1, c0) if shift % 2 == 0 else (c0, c1)
        if np.any(dark != 0):
            raise tex.error("one of the checkerboard's colours must be black (mcvar's checker switches "
                            f"emission on and off); here the squares mcvar leaves dark would be {dark.tolist()}")
        if self.checker is not None and abs(self.checker - period) > 1e-9 * period:
            raise tex.error("every checkerboard emitter of a scene must have the same squares")
        self.checker = period
        return lit

    # emitters ---------------------------------------------------------------
    def emitter(self, node, shape):
        p = self.props(node)
        kind = node.type
        if kind == "area":
            raise node.error("an area emitter must be nested in a <shape>")
        if kind == "point":
            position = p.get("position", ("point",), None)
            to_world = p.get("to_world", ("transform",), None)
            intensity = p.color("intensity", 1.0)
            p.done()
            if isinstance(intensity, Node):
                raise self._texture_error(intensity, "intensity")
            if position is None:
                position = np.zeros(3) if to_world is None else to_world[:3, 3]
            elif to_world is not None:
                raise node.error("give position or to_world, not both")
            if not np.all(intensity >= 0):
                raise node.error("intensity must be non-negative")
            # a black point light emits nothing: dropping it is exact (the exporter writes
            # one where Mitsuba needs an emitter for next-event estimation to choose)
            if np.any(intensity > 0):
                self.points.append((position, intensity))
            return
        if self.environment is not None:
            raise node.error("mcvar has one environment emitter; this is the second")
        if kind == "constant":
            radiance = p.color("radiance", 1.0)
            p.done()
            if isinstance(radiance, Node):
                raise self._texture_error(radiance, "radiance")
            if not np.all(radiance >= 0):
                raise node.error("radiance must be non-negative")
            size = self.root.meta.get("environment_size", "16 32")
            try:
                height, width = (int(v) for v in size.split())
            except ValueError:
                raise SceneFileError(f"{self.root.source}: mcvar comment environment_size={size!r} must be "
                                     "two integers 'height width'") from None
            self.environment = constant(radiance, height=height, width=width)
            return
        if kind == "envmap":
            filename = p.get("filename", ("string",), None)
            scale = p.get("scale", ("float",), 1.0)
            to_world = p.get("to_world", ("transform",), np.eye(4))
            p.done()
            if filename is None:
                raise node.error("missing property 'filename'")
            path = Path(filename)
            if not path.is_absolute():
                path = node.directory / path
            if not path.is_file():
                raise node.error(f"environment image {str(path)!r} does not exist")
            try:
                image = read_image(path)
            except (ValueError, OSError) as exc:
                raise node.error(f"cannot read the environment image: {exc}") from None
            self.environment = EnvironmentMap(envmap_to_mcvar(unrefine(image), to_world, node) * scale)
            return
        raise node.error(f"<emitter type={kind!r}> is not supported")  # pragma: no cover

    # the fields ---------------------------------------------------------------
    def _ray_epsilon(self, extent):
        """``1e-5`` of the scene's extent, or what a ``<!-- mcvar ray_epsilon="..." -->`` comment says."""
        text = self.root.meta.get("ray_epsilon")
        if text is None:
            return max(1e-5 * extent, 1e-7)
        try:
            value = float(text)
        except ValueError:
            raise SceneFileError(f"{self.root.source}: mcvar comment ray_epsilon={text!r} is not a number") from None
        if not (value > 0 and math.isfinite(value)):
            raise SceneFileError(f"{self.root.source}: mcvar comment ray_epsilon must be > 0; got {text!r}")
        return value

    def fields(self):
        tris = np.concatenate(self.triangles) if self.triangles else np.zeros((0, 3, 3))
        n_tri, n_sph = tris.shape[0], len(self.spheres)
        cat = (lambda parts, shape, dtype=np.float64:
               np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype))
        emission = np.concatenate([cat(self.tri_emission, (0, 3)),
                                   np.array(self.sphere_emission, dtype=np.float64).reshape(-1, 3)])
        lights = np.array([np.concatenate(light) for light in self.lights]).reshape(-1, 12)
        # a sphere emitting outwards only is a sphere light (NEE samples the cone it
        # subtends, as Mitsuba samples its sphere emitters); a two-sided one (the
        # furnace seen from inside) stays emission found by BSDF sampling
        sph_emits = np.any(emission[n_tri:] > 0.0, axis=1) & \
            ~np.isin(np.arange(n_sph), sorted(self.two_sided_spheres))
        sphere_light = np.flatnonzero(sph_emits)
        sph_light = np.full(n_sph, -1)
        sph_light[sphere_light] = lights.shape[0] + np.arange(sphere_light.size)
        prim_light = np.concatenate([cat(self.tri_light, (0,), np.int64), sph_light])
        points = np.array([np.concatenate(pt) for pt in self.points]).reshape(-1, 6)
        geometry = [tris.reshape(-1, 3)] + [c[None] + np.array([[r], [-r]]) for c, r in self.spheres]
        pts = np.concatenate(geometry) if n_tri + n_sph else np.zeros((1, 3))
        finite = np.all(np.isfinite(pts), axis=1)
        extent = float(np.linalg.norm(np.ptp(pts[finite], axis=0))) if finite.any() else 1.0
        return dict(
            triangles=tris,
            sphere_centers=np.array([c for c, _ in self.spheres], dtype=np.float64).reshape(-1, 3),
            sphere_radii=np.array([r for _, r in self.spheres], dtype=np.float64),
            prim_material=np.concatenate([cat(self.tri_material, (0,), np.int64),
                                          np.array(self.sphere_material, dtype=np.int64)]),
            prim_emission=emission,
            prim_two_sided_emission=np.concatenate([np.zeros(n_tri, dtype=bool),
                                                    [k in self.two_sided_spheres for k in range(n_sph)]]).astype(bool),
            prim_light=prim_light,
            prim_group=np.concatenate([cat(self.tri_group, (0,), np.int64), np.zeros(n_sph, dtype=np.int64)]),
            materials=tuple(self.materials) if self.materials else (Lambertian(0.5),),
            material_names=tuple(self.material_names) if self.materials else ("default-diffuse",),
            light_origin=lights[:, 0:3], light_edge1=lights[:, 3:6], light_edge2=lights[:, 6:9],
            light_radiance=lights[:, 9:12],
            point_light_position=points[:, 0:3], point_light_intensity=points[:, 3:6],
            sphere_light=sphere_light,
            environment=self.environment,
            checker_period=self.checker,
            ray_epsilon=self._ray_epsilon(extent),
            camera=self.camera,
            render_defaults=dict(self.defaults),
        )


def scene_fields(root: Node) -> dict:
    """The fields of a :class:`mcvar.scene.Scene` for the parsed file ``root``.

    ``camera`` is a dict of :class:`mcvar.scene.Camera` arguments and
    ``render_defaults`` holds what the file says about rendering: ``res``
    (film width, height), ``spp`` (sampler sample_count), ``max_depth``
    (None for Mitsuba's -1) and ``rr_depth`` when given.
    """
    return _Builder(root).build()

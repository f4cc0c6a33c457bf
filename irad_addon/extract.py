"""Scene input: the evaluated depsgraph -> ``SceneData`` (the only bpy-touching part).

``extract_scene(depsgraph)`` walks ``depsgraph.object_instances`` once, so modifiers,
collection instances, vertex/face instancing, particles and geometry-nodes instances
are all covered. Geometry is read with ``foreach_get`` into numpy (exact dtypes, no
per-vertex or per-triangle Python loops) and cached per evaluated mesh datablock, so
N instances of one mesh are triangulated once and transformed N times.

Depsgraph modes (measured with bpy 5.0.1):

* RENDER depsgraph (``RenderEngine.render``): authoritative. It already drops objects
  hidden in render (``hide_render``, also inside instanced collections), collections
  excluded or disabled in render, and children of vertex/face instancers; it uses render
  modifier levels and ``show_instancer_for_render``. Nothing is re-filtered.
* VIEWPORT depsgraph (``context.evaluated_depsgraph_get()``, used by operators): it drops
  excluded collections but keeps render-hidden objects, so we emulate the render rules:
  object ``hide_render`` (of the object and, for instances, of the instancer), collection
  ``hide_render`` along the view layer's collection tree, instancer visibility
  (``show_instancer_for_render``) and the hiding of vertex/face-instanced children.
  Not recoverable from a viewport depsgraph: objects hidden only in the viewport
  (``hide_viewport``, ``hide_set``) are missing, and modifiers use their viewport
  settings (e.g. Subdivision ``levels`` instead of ``render_levels``, particle display
  amount).

Curves, text, surfaces and metaballs: in Blender 5.0 the iterator yields the object
itself (data = Curve/TextCurve/MetaBall) *and* an instance of type MESH carrying its
evaluated mesh, so reading both would double the geometry; we read the MESH instance and
use ``to_mesh()`` only as a fallback for such an object that produced no mesh instance.
"""
from __future__ import annotations

import math

import numpy as np

import bpy

from .scene_data import (AreaLight, Camera, Materials, Mesh, PointLight, SceneData,
                         SpotLight, SunLight, empty_mesh)

DEFAULT_MATERIAL_NAME = "(default surface)"
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)        # Cycles' surface for triangles without material

_GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}
_NON_MESH_GEOMETRY_TYPES = {"CURVE", "SURFACE", "FONT", "META"}
# Reflective BSDFs that are not diffuse: approximated by their colour for now.
_OTHER_BSDFS = {
    "ShaderNodeBsdfAnisotropic", "ShaderNodeBsdfGlossy", "ShaderNodeBsdfGlass",
    "ShaderNodeBsdfMetallic", "ShaderNodeBsdfRefraction", "ShaderNodeBsdfSheen",
    "ShaderNodeBsdfToon", "ShaderNodeBsdfTranslucent", "ShaderNodeSubsurfaceScattering",
    "ShaderNodeBsdfHair", "ShaderNodeBsdfHairPrincipled", "ShaderNodeBsdfVelvet",
}
# Closures that reflect nothing (black for the diffuse model).
_BLACK_CLOSURES = {"ShaderNodeBsdfTransparent", "ShaderNodeHoldout",
                   "ShaderNodeBsdfRayPortal"}


# --------------------------------------------------------------------------- geometry

class _GeometryCache:
    """Triangulated local-space arrays per evaluated mesh datablock (one extraction)."""

    def __init__(self):
        self.entries = {}
        self.triangulations = 0    # how many meshes were actually triangulated

    def get(self, key, mesh):
        entry = self.entries.get(key)
        if entry is None:
            entry = self.entries[key] = triangulate(mesh)
            self.triangulations += 1
        return entry


def triangulate(mesh):
    """Local-space triangles of a bpy Mesh.

    Returns ``(positions (T,3,3) float32, corner_normals (T,3,3) float32,
    material_index (T,) int32)``; the material index is the mesh's slot index.
    """
    mesh.calc_loop_triangles()
    tris = mesh.loop_triangles
    t = len(tris)
    if t == 0:
        return (np.zeros((0, 3, 3), np.float32), np.zeros((0, 3, 3), np.float32),
                np.zeros(0, np.int32))
    loops = np.empty(3 * t, np.int32)
    tris.foreach_get("loops", loops)        # ~0.1-0.3 us per triangle: the slow part
    # Material per triangle through its face: loop_triangles.foreach_get("material_index")
    # is as slow as "loops", the face attribute + loop_triangle_polygons are raw arrays.
    attrs = mesh.attributes
    face_mat = attrs.get("material_index")
    if face_mat is None or face_mat.domain != "FACE":
        mat = np.zeros(t, np.int32)        # the attribute is absent when all are 0
    else:
        tri_face = np.empty(t, np.int32)
        mesh.loop_triangle_polygons.foreach_get("value", tri_face)
        per_face = np.empty(len(mesh.polygons), np.int32)
        face_mat.data.foreach_get("value", per_face)
        mat = per_face[tri_face]

    nv = len(mesh.vertices)
    pos = np.empty(3 * nv, np.float32)
    attrs["position"].data.foreach_get("vector", pos)
    nc = len(mesh.loops)
    corner_vert = np.empty(nc, np.int32)
    cv = attrs.get(".corner_vert")
    if cv is not None:
        cv.data.foreach_get("value", corner_vert)
    else:                                   # older layout
        mesh.loops.foreach_get("vertex_index", corner_vert)
    # Corner normals (4.1+): smooth/flat shading, sharp edges, custom normals.
    cn = np.empty(3 * nc, np.float32)
    mesh.corner_normals.foreach_get("vector", cn)

    positions = pos.reshape(nv, 3)[corner_vert[loops]].reshape(t, 3, 3)
    normals = cn.reshape(nc, 3)[loops].reshape(t, 3, 3)
    return positions, normals, mat


def _transform(positions, normals, matrix):
    """World-space copies for one instance; None if the matrix is degenerate."""
    m = np.asarray(matrix, np.float64)
    if np.array_equal(m, np.eye(4)):
        return positions, normals
    a = m[:3, :3]
    det = float(np.linalg.det(a))
    if not np.isfinite(det) or abs(det) < 1e-30:
        return None
    p = positions.reshape(-1, 3) @ a.T.astype(np.float32)
    p += m[:3, 3].astype(np.float32)
    # Normals by the inverse transpose: n' = (A^-T) n, i.e. row vectors n @ A^-1.
    ata = a.T @ a
    s2 = float(np.trace(ata)) / 3
    if np.allclose(ata, s2 * np.eye(3), rtol=0, atol=1e-6 * s2):
        # Rotation times uniform scale s: A^-1 * s is orthogonal, unit normals stay unit.
        n = normals.reshape(-1, 3) @ (np.linalg.inv(a) * math.sqrt(s2)).astype(np.float32)
    else:
        n = normals.reshape(-1, 3) @ np.linalg.inv(a).astype(np.float32)
        inv_len = np.sqrt(np.einsum("ij,ij->i", n, n))
        inv_len[inv_len == 0] = 1
        np.divide(1, inv_len, out=inv_len)
        n *= inv_len[:, None]
    p = p.reshape(-1, 3, 3)
    n = n.reshape(-1, 3, 3)
    if det < 0:
        # A mirror flips the winding relative to the normals: swap corners 1 and 2 so
        # the geometric normal (v1 - v0) x (v2 - v0) still follows the shading normal.
        p = p[:, (0, 2, 1)]
        n = n[:, (0, 2, 1)]
    return p, n


# -------------------------------------------------------------------------- materials

def _first3(value):
    return np.array(tuple(value)[:3], np.float32)


def _follow(socket):
    """The output socket feeding ``socket``, skipping reroutes and muted links; or None."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if getattr(link, "is_muted", False) or not getattr(link, "is_valid", True):
            return None
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            seen += 1
            continue
        return link.from_socket
    return None


def _srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class _MaterialReader:
    """Turns node trees into the diffuse model's constants; collects warnings."""

    def __init__(self, warnings):
        self.warnings = warnings
        self._image_avg = {}

    def warn(self, message):
        if message not in self.warnings:
            self.warnings.append(message)

    # ----- sockets
    def image_average(self, image, equirect=False):
        key = (image.name_full, equirect)
        if key in self._image_avg:
            return self._image_avg[key]
        avg = None
        try:
            w, h = image.size
            ch = image.channels
            if w > 0 and h > 0 and ch >= 3:
                px = np.empty(w * h * ch, np.float32)
                image.pixels.foreach_get(px)
                px = px.reshape(h, w, ch)[:, :, :3].astype(np.float64)
                # Byte images hold display-encoded values; float buffers are linear.
                if not image.is_float and image.colorspace_settings.name == "sRGB":
                    px = _srgb_to_linear(px)
                if equirect:      # solid-angle weights of the rows (bottom-up)
                    lat = (np.arange(h) + 0.5) / h * math.pi - math.pi / 2
                    wts = np.cos(lat)
                    avg = (px.mean(axis=1) * wts[:, None]).sum(axis=0) / wts.sum()
                else:
                    avg = px.mean(axis=(0, 1))
                avg = avg.astype(np.float32)
        except Exception:         # missing file, unsupported format...
            avg = None
        self._image_avg[key] = avg
        return avg

    def color(self, node, name, fallback, owner):
        """Constant linear RGB of an input socket; texture -> image average or fallback.

        ``fallback`` (None: the socket's own unlinked value) replaces other linked nodes.
        """
        socket = node.inputs[name]
        src = _follow(socket)
        if not socket.is_linked:
            return _first3(socket.default_value)
        if src is None:                   # muted link: Blender uses the socket value
            return _first3(socket.default_value)
        from_node = src.node
        if from_node.bl_idname == "ShaderNodeRGB":
            return _first3(src.default_value)
        image = getattr(from_node, "image", None)
        if from_node.bl_idname in ("ShaderNodeTexImage", "ShaderNodeTexEnvironment") \
                and image is not None:
            equirect = (from_node.bl_idname == "ShaderNodeTexEnvironment"
                        and from_node.projection == "EQUIRECTANGULAR")
            avg = self.image_average(image, equirect)
            if avg is not None:
                self.warn(f"{owner}: '{name}' is textured; using the average colour of "
                          f"image '{image.name}'")
                return avg
        if fallback is None:
            fallback = socket.default_value
        self.warn(f"{owner}: '{name}' is driven by a '{from_node.name}' node; "
                  f"using a constant colour instead")
        return _first3(fallback)

    def value(self, node, name, owner):
        socket = node.inputs[name]
        if socket.is_linked:
            src = _follow(socket)
            if src is not None and src.node.bl_idname == "ShaderNodeValue":
                return float(src.default_value)
            if src is not None:
                self.warn(f"{owner}: '{name}' is driven by a '{src.node.name}' node; "
                          f"using its unlinked value {socket.default_value:g}")
        return float(socket.default_value)

    # ----- closures
    def closure(self, socket, fallback, owner, depth=0):
        """Evaluate the closure feeding ``socket``.

        Returns ``(albedo (3,), emission (3,), kind)``, kind being 'diffuse' (a diffuse
        BSDF), 'black' (emits or absorbs only), 'other' (a non-diffuse BSDF approximated
        by its colour) or 'none' (nothing connected).
        """
        zero = np.zeros(3, np.float32)
        src = _follow(socket)
        if src is None or depth > 64:
            return zero, zero, "none"
        node = src.node
        kind = node.bl_idname
        if kind == "ShaderNodeBsdfPrincipled":
            # Metallic / transmission are ignored here: mirror-like materials come later.
            albedo = self.color(node, "Base Color", fallback, owner)
            emission = (self.color(node, "Emission Color", None, owner)
                        * self.value(node, "Emission Strength", owner))
            return albedo, emission.astype(np.float32), "diffuse"
        if kind == "ShaderNodeBsdfDiffuse":
            return self.color(node, "Color", fallback, owner), zero, "diffuse"
        if kind in ("ShaderNodeEmission", "ShaderNodeBackground"):
            emission = (self.color(node, "Color", fallback if kind == "ShaderNodeBackground"
                                   else None, owner)
                        * self.value(node, "Strength", owner))
            return zero, emission.astype(np.float32), "black"
        if kind in ("ShaderNodeMixShader", "ShaderNodeAddShader"):
            if kind == "ShaderNodeMixShader":
                fac_socket = node.inputs[0]
                if fac_socket.is_linked:
                    self.warn(f"{owner}: a Mix Shader factor is driven by a node; "
                              f"mixing 50/50")
                    f = 0.5
                else:
                    f = min(max(float(fac_socket.default_value), 0.0), 1.0)
                wa, wb = 1.0 - f, f
                sa, sb = node.inputs[1], node.inputs[2]
            else:
                wa = wb = 1.0
                sa, sb = node.inputs[0], node.inputs[1]
            aa, ea, ka = self.closure(sa, fallback, owner, depth + 1)
            ab, eb, kb = self.closure(sb, fallback, owner, depth + 1)
            emission = (wa * ea + wb * eb).astype(np.float32)
            if ka == "none" and kb == "none":
                return zero, emission, "none"
            # A non-diffuse BSDF mixed with a diffuse one: keep the diffuse one's colour
            # (the "first BSDF found" rule); otherwise weight the albedos.
            if ka == "other" and kb in ("diffuse", "black"):
                return ab, emission, kb
            if kb == "other" and ka in ("diffuse", "black"):
                return aa, emission, ka
            albedo = np.clip(wa * aa + wb * ab, 0, 1).astype(np.float32)
            kinds = {ka, kb}
            out = ("diffuse" if "diffuse" in kinds else
                   "other" if "other" in kinds else "black")
            return albedo, emission, out
        if kind in _BLACK_CLOSURES:
            return zero, zero, "black"
        if kind in _OTHER_BSDFS:
            for name in ("Color", "Base Color"):
                if name in node.inputs:
                    return self.color(node, name, fallback, owner), zero, "other"
            return np.asarray(fallback, np.float32)[:3], zero, "other"
        self.warn(f"{owner}: unsupported shader node '{node.name}' ({kind}); "
                  f"using the viewport colour")
        return np.asarray(fallback, np.float32)[:3], zero, "other"

    # ----- datablocks
    def material(self, mat):
        """(albedo (3,), emission (3,)) of a bpy Material."""
        owner = f"Material '{mat.name}'"
        fallback = tuple(mat.diffuse_color)[:3]
        tree = mat.node_tree
        if tree is None:                      # legacy material without nodes
            return np.array(fallback, np.float32), np.zeros(3, np.float32)
        output = _active_output(tree, "ShaderNodeOutputMaterial")
        if output is None:
            return np.zeros(3, np.float32), np.zeros(3, np.float32)
        albedo, emission, kind = self.closure(output.inputs["Surface"], fallback, owner)
        if kind == "other":
            self.warn(f"{owner}: non-diffuse BSDF approximated as diffuse")
        return (np.clip(albedo, 0, 1).astype(np.float32),
                np.maximum(emission, 0).astype(np.float32))

    def world(self, world):
        """Constant background radiance (3,) of a bpy World."""
        if world is None:
            return np.zeros(3, np.float32)
        owner = f"World '{world.name}'"
        fallback = tuple(world.color)[:3]
        tree = world.node_tree                 # Blender 5.0: worlds always use nodes
        if tree is None:
            return np.array(fallback, np.float32)
        output = _active_output(tree, "ShaderNodeOutputWorld")
        if output is None:
            return np.zeros(3, np.float32)
        _, emission, _ = self.closure(output.inputs["Surface"], fallback, owner)
        return np.maximum(emission, 0).astype(np.float32)


def _active_output(tree, idname):
    outputs = [n for n in tree.nodes if n.bl_idname == idname]
    if not outputs:
        return None
    for rank in (lambda n: n.is_active_output and n.target in ("ALL", "CYCLES"),
                 lambda n: n.target in ("ALL", "CYCLES"),
                 lambda n: True):
        for n in outputs:
            if rank(n):
                return n


# ------------------------------------------------------------------------ visibility

def _render_visible_collections(view_layer):
    """Pointers of collections visible in render through the view layer's tree."""
    visible = set()

    def walk(layer_collection):
        coll = layer_collection.collection
        if layer_collection.exclude or coll.hide_render:
            return
        visible.add(coll.original.as_pointer())
        for child in layer_collection.children:
            walk(child)

    walk(view_layer.layer_collection)
    return visible


def _hidden_in_render(inst, visible_collections):
    """Render-visibility rules a VIEWPORT depsgraph does not apply itself."""
    ob = inst.object
    orig = ob.original
    if orig.hide_render:
        return True
    if inst.is_instance:
        parent = inst.parent
        return parent is not None and parent.original.hide_render
    # Not instanced: must sit in a collection that renders in this view layer.
    if not any(c.original.as_pointer() in visible_collections
               for c in orig.users_collection):
        return True
    # Children of vertex/face instancers are only shown through their instances.
    if ob.type != "META" and ob.parent is not None \
            and ob.parent.instance_type in ("VERTS", "FACES"):
        return True
    # Instancers (collection/verts/faces/particles) show themselves per render flag.
    if (ob.is_instancer or len(ob.particle_systems)) and not ob.show_instancer_for_render:
        return True
    return False


def _is_holdout(inst, view_layer_eval):
    def holdout(ob):
        if ob is None:
            return False
        if ob.is_holdout:
            return True
        try:                   # object or its collection set to holdout in the layer
            return bool(ob.holdout_get(view_layer=view_layer_eval))
        except Exception:
            return False
    return holdout(inst.object) or (inst.is_instance and holdout(inst.parent))


# ----------------------------------------------------------------------------- lights

def _light_color(light):
    color = np.array(tuple(light.color)[:3], np.float64)
    if getattr(light, "use_temperature", False):
        color *= np.array(tuple(light.temperature_color)[:3], np.float64)
    return color


def _unit(v):
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def _light_from(ob, matrix, warn):
    """A scene_data light for an evaluated light object, or None (portal, unsupported)."""
    light = ob.data
    cycles = getattr(light, "cycles", None)      # present once Cycles is loaded
    if cycles is not None and getattr(cycles, "is_portal", False):
        return None
    m = np.asarray(matrix, np.float64)
    position = m[:3, 3].copy()
    down = _unit(-m[:3, 2])                     # a light points down its local -Z
    color = _light_color(light)
    power = float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0))
    normalize = bool(getattr(light, "normalize", True))
    if light.type == "POINT":
        r = float(light.shadow_soft_size)
        if not normalize and r > 0:              # Cycles: unnormalised -> no 1/(pi r^2)
            power *= math.pi * r * r
        return PointLight(position, color, power, r)
    if light.type == "SPOT":
        r = float(light.shadow_soft_size)
        if not normalize and r > 0:
            power *= math.pi * r * r
        return SpotLight(position, down, color, power, r,
                         float(light.spot_size), float(light.spot_blend))
    if light.type == "AREA":
        size = float(light.size)
        size_y = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else size
        shape = "RECTANGLE" if light.shape in ("SQUARE", "RECTANGLE") else "ELLIPSE"
        axis_u = m[:3, 0] * size / 2
        axis_v = m[:3, 1] * size_y / 2
        if not normalize:                       # unnormalised: Power is per unit area
            area = 4 * np.linalg.norm(axis_u) * np.linalg.norm(axis_v)
            power *= area * (math.pi / 4 if shape == "ELLIPSE" else 1.0)
        if float(getattr(light, "spread", math.pi)) < math.pi - 1e-6:
            warn(f"Light '{ob.name}': area light spread below 180 degrees is ignored")
        return AreaLight(position, axis_u, axis_v, down, color, power, shape)
    if light.type == "SUN":
        angle = float(light.angle)
        if not normalize and angle > 0:         # unnormalised: strength is radiance
            power *= math.pi * math.sin(angle / 2) ** 2
        return SunLight(_unit(m[:3, 2]), color, power, angle)
    warn(f"Light '{ob.name}': unsupported type {light.type}")
    return None


# ----------------------------------------------------------------------------- camera

def extract_camera(scene, depsgraph, warn):
    cam_ob = scene.camera
    if cam_ob is None:
        return None
    cam_eval = cam_ob.evaluated_get(depsgraph) if depsgraph is not None else cam_ob
    data = cam_eval.data
    if data is None or cam_eval.type != "CAMERA":
        warn(f"Scene camera '{cam_ob.name}' is not a camera object")
        return None
    projection = data.type
    if projection not in ("PERSP", "ORTHO"):
        warn(f"Camera '{cam_ob.name}': {projection} projection is not supported; "
             f"rendering it as perspective")
        projection = "PERSP"
    m = np.array(cam_eval.matrix_world, np.float64)
    for i in range(3):                          # remove scale
        n = np.linalg.norm(m[:3, i])
        if n > 0:
            m[:3, i] /= n
    r = scene.render
    pct = int(r.resolution_percentage)
    return Camera(
        matrix_world=m, projection=projection, lens=float(data.lens),
        sensor_width=float(data.sensor_width), sensor_height=float(data.sensor_height),
        sensor_fit=data.sensor_fit, ortho_scale=float(data.ortho_scale),
        shift_x=float(data.shift_x), shift_y=float(data.shift_y),
        clip_start=float(data.clip_start), clip_end=float(data.clip_end),
        width=int(r.resolution_x) * pct // 100, height=int(r.resolution_y) * pct // 100,
        pixel_aspect_x=float(r.pixel_aspect_x), pixel_aspect_y=float(r.pixel_aspect_y))


# ------------------------------------------------------------------------------ scene

def _is_baked(ob):
    for o in (ob, ob.original):
        try:
            if o.get("irad_baked"):
                return True
        except Exception:
            pass
    return False


def _instance_name(inst):
    """Object name; 'Instancer/Object' for instances; 'Object/Mesh' for geometry-nodes
    instances of foreign geometry (their temporary object carries the host's name)."""
    ob = inst.object
    parent = inst.parent if inst.is_instance else None
    if parent is None:
        return ob.name
    if parent.original == ob.original:
        data, own = ob.data, ob.original.data
        if data is not None and own is not None and data.name != own.name:
            return f"{ob.name}/{data.name}"
        return ob.name
    return f"{parent.name}/{ob.name}"


class _Extraction:
    """State of one extract_scene call."""

    def __init__(self, depsgraph, include_baked):
        self.depsgraph = depsgraph
        self.include_baked = include_baked
        self.render_mode = depsgraph.mode == "RENDER"
        self.warnings = []
        self.reader = _MaterialReader(self.warnings)
        self.cache = _GeometryCache()
        self.view_layer_eval = depsgraph.view_layer_eval
        self.visible_collections = (None if self.render_mode else
                                    _render_visible_collections(depsgraph.view_layer))
        self.parts = []           # (positions, normals, material_index, object_index)
        self.object_names = []
        self.object_holdout = []
        self.material_ids = {}    # material key -> global index
        self.albedo = []
        self.emission = []
        self.material_names = []
        self.lights = []
        self.mesh_parents = set()     # objects that yielded a MESH instance of themselves
        self.to_mesh_candidates = []  # non-instanced curve/text/... objects
        self.to_mesh_count = 0

    def warn(self, message):
        if message not in self.warnings:
            self.warnings.append(message)

    def material_index(self, mat):
        key = None if mat is None else mat.original.as_pointer()
        idx = self.material_ids.get(key)
        if idx is None:
            if mat is None:
                albedo = np.array(DEFAULT_ALBEDO, np.float32)
                emission = np.zeros(3, np.float32)
                name = DEFAULT_MATERIAL_NAME
            else:
                albedo, emission = self.reader.material(mat)
                name = mat.name
            idx = self.material_ids[key] = len(self.albedo)
            self.albedo.append(albedo)
            self.emission.append(emission)
            self.material_names.append(name)
        return idx

    def slot_table(self, ob, mesh):
        """Global material index for each of the object's material slots."""
        mats = [slot.material for slot in ob.material_slots]
        if not mats and mesh is not None and len(mesh.materials):
            mats = list(mesh.materials)
        if not mats:
            mats = [None]
        return np.array([self.material_index(m) for m in mats], np.int32)

    def add_mesh(self, inst, key, mesh, ob=None, matrix=None, name=None, holdout=None):
        """One instance of a mesh. ``inst`` may be None when ``ob``, ``matrix``, ``name``
        and ``holdout`` are given (DepsgraphObjectInstance dies with its iteration)."""
        if inst is not None:
            ob, matrix = inst.object, inst.matrix_world
        positions, normals, local_mat = self.cache.get(key, mesh)
        if positions.shape[0] == 0:
            return
        world = _transform(positions, normals, matrix)
        if world is None:
            return
        table = self.slot_table(ob, mesh)
        gmat = table[np.clip(local_mat, 0, len(table) - 1)]
        oid = len(self.object_names)
        self.object_names.append(_instance_name(inst) if inst is not None else name)
        self.object_holdout.append(_is_holdout(inst, self.view_layer_eval)
                                   if inst is not None else holdout)
        self.parts.append((world[0], world[1], gmat, oid))

    def visit(self, inst):
        ob = inst.object
        if ob is None:
            return
        if self.render_mode:
            if not inst.show_self:          # e.g. an instancer hidden in render
                return
        elif _hidden_in_render(inst, self.visible_collections):
            return
        kind = ob.type
        if kind == "LIGHT":
            if not self.include_baked and _is_baked(ob):
                return
            light = _light_from(ob, inst.matrix_world, self.warn)
            if light is not None:
                self.lights.append(light)
            return
        if kind not in _GEOMETRY_TYPES:
            return
        data = ob.data
        if isinstance(data, bpy.types.Mesh):
            if inst.is_instance and inst.parent is not None:
                self.mesh_parents.add(inst.parent.original.as_pointer())
            self.add_mesh(inst, ("mesh", data.as_pointer()), data)
        elif kind in _NON_MESH_GEOMETRY_TYPES and not inst.is_instance:
            # Normally its mesh arrives as a separate MESH instance; see the module doc.
            # Not instanced, so ob is the depsgraph's own evaluated object: still valid
            # after the iteration, unlike inst.
            self.to_mesh_candidates.append(
                (ob, np.array(inst.matrix_world), _instance_name(inst),
                 _is_holdout(inst, self.view_layer_eval)))

    def flush_to_mesh(self):
        for ob, matrix, name, holdout in self.to_mesh_candidates:
            if ob.original.as_pointer() in self.mesh_parents:
                continue
            try:
                mesh = ob.to_mesh()
            except RuntimeError:
                continue
            try:
                if mesh is not None:
                    self.to_mesh_count += 1
                    self.add_mesh(None, ("to_mesh", ob.original.as_pointer()), mesh,
                                  ob=ob, matrix=matrix, name=name, holdout=holdout)
            finally:
                ob.to_mesh_clear()

    def mesh(self):
        if not self.parts:
            out = empty_mesh()
            out.object_holdout = np.zeros(0, bool)
            return out
        counts = [p[0].shape[0] for p in self.parts]
        triangles = np.concatenate([p[0] for p in self.parts]).astype(np.float32, copy=False)
        normals = np.concatenate([p[1] for p in self.parts]).astype(np.float32, copy=False)
        material = np.concatenate([p[2] for p in self.parts]).astype(np.int32, copy=False)
        object_index = np.repeat(np.array([p[3] for p in self.parts], np.int32), counts)
        return Mesh(triangles, normals, material, object_index, list(self.object_names),
                    np.array(self.object_holdout, bool))

    def materials(self):
        if not self.albedo:
            return Materials(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), [])
        return Materials(np.array(self.albedo, np.float32),
                         np.array(self.emission, np.float32), list(self.material_names))


def extract_scene(depsgraph, scene=None, include_baked=False, stats=None) -> SceneData:
    """Everything a final render sees, as plain arrays.

    ``depsgraph``: an evaluated depsgraph; a RENDER one is authoritative, a VIEWPORT one
    gets the render-visibility rules re-applied (see the module docstring).
    ``scene`` defaults to ``depsgraph.scene`` (render settings, camera, world).
    ``include_baked``: keep lights whose object has the custom property ``irad_baked``.
    ``stats``: optional dict filled with counters: ``triangulations`` (meshes actually
    triangulated), ``instances`` (depsgraph instances visited), ``to_mesh`` (fallbacks).
    """
    if scene is None:
        scene = depsgraph.scene
    ex = _Extraction(depsgraph, include_baked)
    instances = 0
    for inst in depsgraph.object_instances:
        instances += 1
        ex.visit(inst)
    ex.flush_to_mesh()

    world = scene.world
    if world is not None:
        try:
            world = world.evaluated_get(depsgraph)
        except Exception:
            pass
    world_radiance = ex.reader.world(world)
    camera = extract_camera(scene, depsgraph, ex.warn)
    if stats is not None:
        stats["triangulations"] = ex.cache.triangulations
        stats["instances"] = instances
        stats["to_mesh"] = ex.to_mesh_count
    return SceneData(mesh=ex.mesh(), materials=ex.materials(), lights=ex.lights,
                     world_radiance=np.asarray(world_radiance, np.float32),
                     camera=camera, warnings=ex.warnings)

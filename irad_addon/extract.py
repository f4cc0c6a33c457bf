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

Node trees (materials, world) are read by ``extract_materials``, light objects by
``extract_lights``.
"""
from __future__ import annotations

import math

import numpy as np

import bpy

from .extract_lights import is_baked, light_from
from .extract_materials import MaterialReader
from .scene_data import Camera, Materials, Mesh, SceneData, empty_mesh

DEFAULT_MATERIAL_NAME = "(default surface)"
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)        # Cycles' surface for triangles without material

_GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}
_NON_MESH_GEOMETRY_TYPES = {"CURVE", "SURFACE", "FONT", "META"}


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
        self.reader = MaterialReader(self.warnings)
        self.cache = _GeometryCache()
        self.view_layer_eval = depsgraph.view_layer_eval
        self.visible_collections = (None if self.render_mode else
                                    _render_visible_collections(depsgraph.view_layer))
        self.parts = []           # (positions, normals, material_index, object_index)
        self.object_names = []
        self.object_holdout = []
        self.material_ids = {}    # material key -> global index
        self.albedo = []
        self.mirror = []
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
                emission = mirror = np.zeros(3, np.float32)
                name = DEFAULT_MATERIAL_NAME
            else:
                albedo, emission, mirror = self.reader.material(mat)
                name = mat.name
            idx = self.material_ids[key] = len(self.albedo)
            self.albedo.append(albedo)
            self.emission.append(emission)
            self.mirror.append(mirror)
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
            if not self.include_baked and is_baked(ob):
                return
            light = light_from(ob, inst.matrix_world, self.warn)
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
        mirror = np.array(self.mirror, np.float32)
        return Materials(np.array(self.albedo, np.float32),
                         np.array(self.emission, np.float32), list(self.material_names),
                         mirror if mirror.any() else None)


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

"""Bounce lights baked from VPLs: Blender area lights in our own collection (bpy glue).

Everything created here carries the custom property ``irad_baked`` (objects, light
datablocks, their actions and the collection), so that extraction skips the lights
(``extract_lights.is_baked``: a second bake does not trace the first one's lights) and
``clear`` removes exactly what a bake made, even after the collection was renamed.
The math (power, orientation, size, padding of animation frames) is in ``bake_math``.
"""
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from . import bake_math, extract, light_tree, preferences, render, variants, vpl
from .engine import render_settings
from .frame import InvalidScene, check_renderable, prepare_frame
from .rays import RayTracerCache

COLLECTION_NAME = "IRAD Bounce Lights"
TAG = "irad_baked"               # the key extract_lights.is_baked looks for
LIGHT_NAME = "IRAD Bounce"

# Shared by bakes of unchanged geometry (animation frames, re-bakes after moving a light).
_tracer_cache = RayTracerCache()
# Last traced VPLs per scene name: for the overlay and the status line (not saved).
_memory = {}


class BakeError(ValueError):
    """The scene cannot be baked; the message says why, for the user."""


@dataclass
class Traced:
    """VPLs of one frame and what the bake needs beside them."""
    vpls: vpl.VPLs
    clamp_distance: float
    scene_radius: float
    tracer: object               # the frame's RayTracer, to fit lights into free space
    frame_number: int
    seconds: float
    warnings: list = field(default_factory=list)


# ------------------------------------------------------------------------ tracing

def prepare(scene, depsgraph):
    """Extract and prepare the scene as the renderer would; BakeError if unusable."""
    data = extract.extract_scene(depsgraph, scene=scene, include_baked=False)
    try:
        check_renderable(data)
    except InvalidScene as error:
        raise BakeError(str(error)) from None
    if len(data.mesh.triangles) == 0:
        raise BakeError("The scene has no mesh: bounce light needs surfaces to bounce off")
    frame = prepare_frame(data, _tracer_cache if preferences.use_cache() else None)
    if not frame.emitters:
        raise BakeError("The scene has no light with non-zero power (lights, emissive "
                        "materials or world): there is no light to bounce")
    return frame


def trace_vpls(frame, settings, cancel=None, state=None):
    """The one call site that turns a prepared frame into VPLs for the chosen variant;
    `state` (a variants.VariantState) carries incremental IR across animation frames."""
    return variants.vpls_for_frame(frame, settings, state, cancel)[0]


def new_variant_state():
    """State shared by the frames of one animation bake (operators stay bpy-thin)."""
    return variants.VariantState()


def trace(scene, frame, cancel=None, state=None):
    settings = render_settings(scene)
    if settings.max_bounces < 1:
        raise BakeError("Max Bounces is 0: there is no bounce light to bake")
    t0 = time.perf_counter()
    vpls = trace_vpls(frame, settings, cancel, state)
    seconds = time.perf_counter() - t0
    if vpls.count == 0:
        raise BakeError("No particle hit a reflecting surface: nothing to bake (are all "
                        "surfaces black, or do the lights face away from the scene?)")
    return Traced(vpls, render.clamp_distance(frame, vpls, settings.clamp),
                  float(frame.bounds[1]), frame.tracer, scene.frame_current, seconds,
                  list(frame.scene.warnings))


def remember(scene, traced):
    _memory[scene.name_full] = traced


def remembered(scene):
    return _memory.get(scene.name_full)


def forget_all():
    _memory.clear()


# ------------------------------------------------------------------ light planning

def plan_lights(traced, budget):
    """Disk lights for the VPLs: one per VPL within the budget, else one per light-tree
    cluster (Walter 2005) with the cluster's total flux."""
    v = traced.vpls
    if v.count <= budget:
        return bake_math.disk_lights(v.position, v.normal, v.flux, traced.clamp_distance,
                                     traced.scene_radius, traced.tracer)
    clusters = light_tree.cluster_by_budget(v.position, v.normal, v.flux, budget)
    return bake_math.clustered_disk_lights(v.position, v.normal, v.flux, clusters,
                                           traced.clamp_distance, traced.scene_radius,
                                           traced.tracer)


# -------------------------------------------------------------------- our datablocks

def is_ours(idblock):
    return bool(idblock is not None and idblock.get(TAG))


def _tag(idblock):
    idblock[TAG] = True


def baked_objects(scene):
    return [ob for ob in scene.collection.all_objects if is_ours(ob)]


def baked_collections(scene):
    return [c for c in scene.collection.children_recursive if is_ours(c)]


def _actions_of(idblock):
    ad = idblock.animation_data if idblock is not None else None
    return [ad.action] if ad is not None and ad.action is not None else []


def clear(scene):
    """Remove this scene's baked lights, their light data and actions, and our (then
    empty) collections. Returns (objects removed, names of collections kept because the
    user put something of their own in them)."""
    objects = baked_objects(scene)
    lights = {ob.data for ob in objects if is_ours(ob.data)}
    actions = {a for idb in objects + list(lights) for a in _actions_of(idb) if is_ours(a)}
    count = len(objects)
    if objects:
        bpy.data.batch_remove(objects)
    # Ours only once nothing else uses them (a user may have linked our light data).
    orphans = [d for d in lights if d.users == 0]
    if orphans:
        bpy.data.batch_remove(orphans)
    orphans = [a for a in actions if a.users == 0]
    if orphans:
        bpy.data.batch_remove(orphans)
    kept = []
    empty = []
    for coll in baked_collections(scene):
        (kept if len(coll.objects) or len(coll.children) else empty).append(coll)
    if empty:
        bpy.data.batch_remove(empty)
    return count, [c.name for c in kept]


def ensure_collection(scene):
    """Our collection in this scene (found by tag, so renaming is fine), else a new one."""
    for coll in baked_collections(scene):
        return coll
    coll = bpy.data.collections.new(COLLECTION_NAME)
    _tag(coll)
    scene.collection.children.link(coll)
    return coll


def _new_lights(collection, count, influence):
    """`count` tagged disk area lights, each with its own light datablock."""
    objects = []
    for i in range(count):
        name = f"{LIGHT_NAME} {i:04d}"
        data = bpy.data.lights.new(name, 'AREA')
        data.shape = 'DISK'
        # EEVEE culls a light where its influence falls below a threshold, which would
        # cut weak bounce lights short: give each the whole scene.
        if hasattr(data, "use_custom_distance"):
            data.use_custom_distance = True
            data.cutoff_distance = influence
        # Baked disks overlap on their surfaces, and a Cycles BSDF ray that hits several
        # coincident lights counts only one of them, so the multiple-importance weight
        # it takes from light sampling is lost (measured: -58% with ~6 overlapping
        # disks). Light sampling alone is exact and, for these small lights, no noisier.
        cycles = getattr(data, "cycles", None)
        if cycles is not None:
            cycles.use_multiple_importance_sampling = False
        _tag(data)
        ob = bpy.data.objects.new(name, data)
        ob.rotation_mode = 'QUATERNION'
        _tag(ob)
        collection.objects.link(ob)
        objects.append(ob)
    return objects


def _place(objects, lights, row=slice(None)):
    """Set every light's transform, power, colour and size from BakedLights arrays."""
    location = lights["location"][row].tolist()
    rotation = lights["rotation"][row].tolist()
    energy = lights["energy"][row].tolist()
    color = lights["color"][row].tolist()
    size = lights["size"][row].tolist()
    for i, ob in enumerate(objects):
        ob.location = location[i]
        ob.rotation_quaternion = rotation[i]
        data = ob.data
        data.energy = energy[i]
        data.color = color[i]
        data.size = size[i]


def _arrays(lights):
    return {name: getattr(lights, name)
            for name in ("location", "rotation", "energy", "color", "size")}


def bake_static(scene, lights, scene_radius):
    """Replace the scene's baked lights with `lights` (BakedLights); returns the objects."""
    clear(scene)
    objects = _new_lights(ensure_collection(scene), lights.count, 4.0 * scene_radius)
    _place(objects, _arrays(lights))
    return objects


# ------------------------------------------------------------------------ animation

_OBJECT_CHANNELS = (("location", 3), ("rotation_quaternion", 4))
_LIGHT_CHANNELS = (("energy", 1), ("color", 3), ("size", 1))
_ARRAY_OF = {"location": "location", "rotation_quaternion": "rotation", "energy": "energy",
             "color": "color", "size": "size"}


def _fcurves(idblock):
    """F-curves of the action slot assigned to an ID (layered actions, Blender >= 4.4;
    the action's own list before)."""
    anim = idblock.animation_data
    try:
        from bpy_extras.anim_utils import animdata_get_channelbag_for_assigned_slot
    except ImportError:
        return anim.action.fcurves
    return animdata_get_channelbag_for_assigned_slot(anim).fcurves


def _key_series(idblock, channels, frames, values):
    """Constant-interpolated keys at `frames` for each (data_path, width): one
    keyframe_insert creates the curves, then all frames are written at once."""
    for path, _ in channels:
        idblock.keyframe_insert(path, frame=float(frames[0]))
    for curve in _fcurves(idblock):
        series = values.get(curve.data_path)
        if series is None:
            continue
        column = series if series.ndim == 1 else series[:, curve.array_index]
        points = curve.keyframe_points
        if len(points) < len(frames):
            points.add(len(frames) - len(points))
        co = np.empty(2 * len(frames), np.float32)
        co[0::2] = frames
        co[1::2] = column
        points.foreach_set("co", co)
        points.foreach_set("interpolation", np.zeros(len(frames), np.int32))  # CONSTANT
        curve.update()


def bake_animated(scene, frame_numbers, per_frame, scene_radius):
    """Replace the baked lights with a pool keyed at every frame: light i shows frame f's
    i-th light (power 0 when that frame has fewer). Constant interpolation: a rebuilt
    light set has no identity between frames, so nothing may slide between them."""
    clear(scene)
    padded = bake_math.pad_frames(per_frame)
    count = padded["energy"].shape[1]
    objects = _new_lights(ensure_collection(scene), count, 4.0 * scene_radius)
    _place(objects, padded, row=0)
    frames = np.asarray(frame_numbers, np.float32)
    for i, ob in enumerate(objects):
        values = {path: padded[_ARRAY_OF[path]][:, i] for path in _ARRAY_OF}
        _key_series(ob, _OBJECT_CHANNELS, frames, values)
        _key_series(ob.data, _LIGHT_CHANNELS, frames, values)
        for action in _actions_of(ob) + _actions_of(ob.data):
            _tag(action)
    return objects


# --------------------------------------------------------------------------- status

def record_status(scene, vpls=None, lights=None, seconds=None, error=None):
    """What the sidebar's status line shows (stored on scene.irad); None keeps a value."""
    irad = scene.irad
    for name, value in (("bake_vpl_count", vpls), ("bake_light_count", lights),
                        ("bake_seconds", seconds), ("bake_relative_error", error)):
        if value is not None:
            setattr(irad, name, value)

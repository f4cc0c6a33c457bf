"""Bake, clear and animate bounce lights (thin wrappers over irad_addon.bake)."""
import time

import bpy
from bpy.props import BoolProperty, IntProperty

from ..irad_addon import bake
from ..irad_addon.bake import BakeError
from .job import JobOperator
from .vpls import report_warnings, trace_current_frame


class IRAD_OT_bake_lights(JobOperator, bpy.types.Operator):
    bl_idname = "irad.bake_lights"
    bl_label = "Bake Bounce Lights"
    bl_description = ("Replace the baked bounce lights with disk lights made from this "
                      "frame's VPLs (clustered down to the light budget), in the "
                      f"'{bake.COLLECTION_NAME}' collection")

    def steps(self, scene):
        t0 = time.perf_counter()
        traced = yield from trace_current_frame(scene)
        budget = scene.irad.light_budget
        clustering = traced.vpls.count > budget
        yield 0.5, f"Clustering {traced.vpls.count} VPLs" if clustering else "Planning lights"
        lights = bake.plan_lights(traced, budget)
        yield 0.7, f"Creating {lights.count} lights"
        bake.bake_static(scene, lights, traced.scene_radius)
        seconds = time.perf_counter() - t0
        bake.remember(scene, traced)
        bake.record_status(scene, traced.vpls.count, lights.count, seconds,
                           lights.relative_error)
        report_warnings(self, traced)
        self.report({'INFO'}, f"Baked {lights.count} lights from {traced.vpls.count} VPLs "
                              f"in {seconds:.2f} s")
        yield 1.0, "Done"


class IRAD_OT_clear_lights(bpy.types.Operator):
    bl_idname = "irad.clear_lights"
    bl_label = "Clear Bounce Lights"
    bl_description = ("Remove the lights, light data, animation and collection that "
                      "Bake Bounce Lights created in this scene, and nothing else")
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        scene = context.scene
        if not bake.baked_objects(scene) and not bake.baked_collections(scene):
            self.report({'ERROR'}, "Nothing to clear: this scene has no baked bounce lights")
            return {'CANCELLED'}
        count, kept = bake.clear(scene)
        bake.record_status(scene, lights=0)
        for name in kept:
            self.report({'WARNING'}, f"Kept collection '{name}': it holds objects that "
                                     f"are not baked lights")
        self.report({'INFO'}, f"Removed {count} baked lights")
        return {'FINISHED'}


class IRAD_OT_bake_animation(JobOperator, bpy.types.Operator):
    bl_idname = "irad.bake_animation"
    bl_label = "Bake Bounce Light Animation"
    bl_description = ("Bake bounce lights for every frame of a range and keyframe their "
                      "power, colour, size and transform (for playback and batch renders)")

    use_scene_range: BoolProperty(name="Scene Frame Range", default=True,
                                  description="Bake the scene's frame range; otherwise "
                                              "Start and End below")
    frame_start: IntProperty(name="Start", default=1,
                             description="First frame to bake")
    frame_end: IntProperty(name="End", default=250,
                           description="Last frame to bake")

    def frame_range(self, scene):
        if self.use_scene_range:
            return scene.frame_start, scene.frame_end
        return self.frame_start, self.frame_end

    def steps(self, scene):
        start, end = self.frame_range(scene)
        if end < start:
            raise BakeError(f"The frame range {start}-{end} is empty")
        frames = list(range(start, end + 1))
        budget = scene.irad.light_budget
        t0 = time.perf_counter()
        original = scene.frame_current
        per_frame, last = [], None
        radius = 0.0
        state = bake.new_variant_state()   # incremental IR keeps its VPLs across frames
        try:
            for i, number in enumerate(frames):
                scene.frame_set(number)
                try:
                    frame = bake.prepare(scene, bpy.context.evaluated_depsgraph_get())
                    last = bake.trace(scene, frame, state=state)
                except BakeError as error:
                    raise BakeError(f"Frame {number}: {error}") from None
                per_frame.append(bake.plan_lights(last, budget))
                radius = max(radius, last.scene_radius)
                yield (i + 1) / (len(frames) + 1), f"Frame {number}: {last.vpls.count} VPLs"
        finally:
            scene.frame_set(original)
        objects = bake.bake_animated(scene, frames, per_frame, radius)
        seconds = time.perf_counter() - t0
        bake.remember(scene, last)
        error = max(lights.relative_error for lights in per_frame)
        bake.record_status(scene, last.vpls.count, len(objects), seconds, error)
        report_warnings(self, last)
        self.report({'INFO'}, f"Baked {len(frames)} frames into {len(objects)} keyframed "
                              f"lights in {seconds:.1f} s")
        yield 1.0, "Done"


classes = (IRAD_OT_bake_lights, IRAD_OT_clear_lights, IRAD_OT_bake_animation)

"""irad.compute_vpls: trace the current frame's VPLs and keep them for the overlay."""
import bpy

from ..irad_addon import bake, overlay
from .job import JobOperator


def report_warnings(operator, traced):
    for message in traced.warnings:
        operator.report({'WARNING'}, message)


def trace_current_frame(scene):
    """Generator steps shared by the operators: prepare, then trace; returns Traced."""
    yield 0.0, "Reading the scene"
    frame = bake.prepare(scene, bpy.context.evaluated_depsgraph_get())
    yield 0.2, "Shooting particles"
    return bake.trace(scene, frame)


class IRAD_OT_compute_vpls(JobOperator, bpy.types.Operator):
    bl_idname = "irad.compute_vpls"
    bl_label = "Compute VPLs"
    bl_description = ("Trace the virtual point lights of the current frame and keep them in "
                      "memory (shown by the VPL overlay); no datablock is created")

    def steps(self, scene):
        traced = yield from trace_current_frame(scene)
        bake.remember(scene, traced)
        bake.record_status(scene, vpls=traced.vpls.count, seconds=traced.seconds)
        overlay.redraw()
        report_warnings(self, traced)
        self.report({'INFO'}, f"{traced.vpls.count} VPLs in {traced.seconds:.2f} s")
        yield 1.0, "Done"


classes = (IRAD_OT_compute_vpls,)

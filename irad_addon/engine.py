"""The INSTANT_RADIOSITY RenderEngine: Blender glue around render.render_frame."""
import bpy


class InstantRadiosityEngine(bpy.types.RenderEngine):
    bl_idname = "INSTANT_RADIOSITY"
    bl_label = "Instant Radiosity"
    bl_use_preview = False

    def render(self, depsgraph):
        raise NotImplementedError  # filled in by the render pipeline


def register():
    bpy.utils.register_class(InstantRadiosityEngine)


def unregister():
    bpy.utils.unregister_class(InstantRadiosityEngine)

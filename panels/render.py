"""Render Properties panels for the Instant Radiosity engine."""
import bpy

ENGINE = "INSTANT_RADIOSITY"


class IRadRenderPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class RENDER_PT_irad_sampling(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        irad = context.scene.irad
        col = layout.column()
        col.prop(irad, "aa_samples")
        col.prop(irad, "interleave")
        col.prop(irad, "light_samples")
        col.prop(irad, "seed")
        col.prop(irad, "use_animated_seed")


class RENDER_PT_irad_indirect(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Global Illumination"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        irad = context.scene.irad
        col = layout.column()
        col.prop(irad, "variant")
        col.prop(irad, "particles")
        col.prop(irad, "max_bounces")
        col.prop(irad, "clamp")


classes = (RENDER_PT_irad_sampling, RENDER_PT_irad_indirect)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)

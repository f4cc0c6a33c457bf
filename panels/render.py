"""Render Properties panels for the Instant Radiosity engine."""
import bpy

ENGINE = "INSTANT_RADIOSITY"


class IRadRenderPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}
    properties = ()   # scene.irad properties the panel shows, in order

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        draw_properties(self.layout, context.scene.irad, self.properties)


def draw_properties(layout, irad, names):
    """The scene.irad properties `names` in one column, labels beside them."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    col = layout.column()
    for name in names:
        col.prop(irad, name)


class RENDER_PT_irad_sampling(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Sampling"
    properties = ("aa_samples", "coverage_samples", "interleave", "light_samples", "sequence", "seed",
                  "use_animated_seed")


class RENDER_PT_irad_indirect(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Global Illumination"
    properties = ("variant", "particles", "max_bounces", "clamp", "bias_compensation",
                  "shadow_ray_budget")


class RENDER_PT_irad_walkthrough(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Reuse Across Frames"
    bl_parent_id = "RENDER_PT_irad_indirect"
    properties = ("temporal_frames",)

    def draw_header(self, context):
        self.layout.prop(context.scene.irad, "temporal_reuse", text="")

    def draw(self, context):
        irad = context.scene.irad
        # Only classic IR's paths are independent of the camera.
        self.layout.active = irad.temporal_reuse and irad.variant == 'CLASSIC'
        draw_properties(self.layout, irad, self.properties)


class RENDER_PT_irad_lightcuts(IRadRenderPanel, bpy.types.Panel):
    bl_label = "Lightcuts"
    bl_parent_id = "RENDER_PT_irad_indirect"
    properties = ("lightcut_error", "max_cut")

    def draw_header(self, context):
        self.layout.prop(context.scene.irad, "use_lightcuts", text="")

    def draw(self, context):
        self.layout.active = context.scene.irad.use_lightcuts
        draw_properties(self.layout, context.scene.irad, self.properties)


classes = (RENDER_PT_irad_sampling, RENDER_PT_irad_indirect, RENDER_PT_irad_walkthrough,
           RENDER_PT_irad_lightcuts)
register, unregister = bpy.utils.register_classes_factory(classes)

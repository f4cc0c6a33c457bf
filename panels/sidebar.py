"""3D Viewport sidebar (N panel), tab "Instant Radiosity": bake bounce lights from VPLs.
Shown with any render engine: the baked lights serve EEVEE and Cycles."""
import bpy


class IRadSidebarPanel:
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Instant Radiosity"


def _split(layout):
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class VIEW3D_PT_irad_bake(IRadSidebarPanel, bpy.types.Panel):
    bl_label = "Bounce Lights"

    def draw(self, context):
        layout = _split(self.layout)
        irad = context.scene.irad
        col = layout.column()
        col.prop(irad, "variant")
        col.prop(irad, "particles")
        col.prop(irad, "max_bounces")
        col.prop(irad, "clamp")
        col.prop(irad, "seed")
        col.prop(irad, "light_budget")
        layout.separator()
        col = layout.column(align=True)
        col.operator("irad.bake_lights", icon='LIGHT_AREA')
        col.operator("irad.clear_lights", icon='TRASH')


class VIEW3D_PT_irad_animation(IRadSidebarPanel, bpy.types.Panel):
    bl_label = "Animation"
    bl_parent_id = "VIEW3D_PT_irad_bake"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = _split(self.layout)
        scene = context.scene
        col = layout.column(align=True)
        col.prop(scene, "frame_start", text="Frame Start")
        col.prop(scene, "frame_end", text="End")
        layout.operator("irad.bake_animation", icon='RENDER_ANIMATION')


class VIEW3D_PT_irad_vpls(IRadSidebarPanel, bpy.types.Panel):
    bl_label = "VPLs"
    bl_parent_id = "VIEW3D_PT_irad_bake"

    def draw_header(self, context):
        self.layout.prop(context.scene.irad, "show_vpl_overlay", text="")

    def draw(self, context):
        layout = _split(self.layout)
        layout.operator("irad.compute_vpls", icon='OUTLINER_OB_LIGHTPROBE')
        layout.prop(context.scene.irad, "show_vpl_overlay")


class VIEW3D_PT_irad_status(IRadSidebarPanel, bpy.types.Panel):
    bl_label = "Status"
    bl_parent_id = "VIEW3D_PT_irad_bake"

    def draw(self, context):
        layout = self.layout
        irad = context.scene.irad
        col = layout.column(align=True)
        col.label(text=f"VPLs: {irad.bake_vpl_count}", icon='LIGHT')
        col.label(text=f"Lights: {irad.bake_light_count} of {irad.light_budget} budget",
                  icon='LIGHT_AREA')
        col.label(text=f"Estimated error: {100 * irad.bake_relative_error:.1f}%",
                  icon='INFO')
        col.label(text=f"Last bake: {irad.bake_seconds:.2f} s", icon='TIME')


classes = (VIEW3D_PT_irad_bake, VIEW3D_PT_irad_animation, VIEW3D_PT_irad_vpls,
           VIEW3D_PT_irad_status)


register, unregister = bpy.utils.register_classes_factory(classes)

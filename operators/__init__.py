"""Operators (bl_idname under irad.): thin wrappers over irad_addon."""
import bpy

from . import bake, vpls

classes = vpls.classes + bake.classes


register, unregister = bpy.utils.register_classes_factory(classes)

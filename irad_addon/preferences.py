"""Add-on preferences: worker threads and the ray-tracing cache (Edit > Preferences)."""
import os

import bpy
from bpy.props import BoolProperty, IntProperty

from . import rays

# Preferences belong to the add-on's root package (bl_ext.<repo>.instant_radiosity),
# not to this sub-package.
ADDON_PACKAGE = __package__.rpartition('.')[0]


class IRadPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    threads: IntProperty(name="Threads", default=0, min=0, soft_max=64, max=1024,
                         update=lambda self, context: rays.set_worker_count(self.threads),
                         description="Threads for ray tracing and gathering; 0 uses one per "
                                     "CPU core")
    use_cache: BoolProperty(name="Reuse Ray-Tracing Data", default=True,
                            description="Keep the ray-tracing acceleration structure between "
                                        "renders and bakes while the geometry is unchanged "
                                        "(faster animations; uses memory)")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.prop(self, "threads")
        col.label(text=f"Using {thread_count()} of {os.cpu_count() or 1} CPU threads",
                  icon='INFO')
        col.prop(self, "use_cache")


def get():
    """The preferences, or None while the add-on is not enabled (e.g. some test setups)."""
    addon = bpy.context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon is not None else None


def thread_count():
    """Worker threads to use: the preference, or one per CPU core when it is 0."""
    prefs = get()
    chosen = prefs.threads if prefs is not None else 0
    return chosen if chosen > 0 else max(1, os.cpu_count() or 1)


def use_cache():
    prefs = get()
    return True if prefs is None else bool(prefs.use_cache)


classes = (IRadPreferences,)


_register, unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    prefs = get()
    rays.set_worker_count(prefs.threads if prefs is not None else 0)

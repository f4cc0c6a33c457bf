# Instant Radiosity for Blender: registration only; the engine lives in irad_addon.
from .irad_addon import engine, overlay, preferences, properties
from . import operators, panels

_modules = (preferences, properties, engine, overlay, operators, panels)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()

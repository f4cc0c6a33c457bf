# Instant Radiosity for Blender: registration only; the engine lives in irad_addon.
from .irad_addon import engine, properties
from . import operators, panels

_modules = (properties, engine, operators, panels)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()

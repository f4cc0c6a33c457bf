"""UI panels (thin): Render Properties when our engine is active."""
import bpy

from . import render

_modules = (render,)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()

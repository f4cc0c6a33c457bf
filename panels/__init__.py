"""UI panels (thin): Render Properties when our engine is active, and the 3D Viewport
sidebar for baking bounce lights."""
import bpy

from . import render, sidebar

_modules = (render, sidebar)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()

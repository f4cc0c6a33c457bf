"""3D Viewport overlay: the last computed VPLs as points coloured by flux (gpu glue).

One draw handler serves every scene; it is installed while any scene has
``irad.show_vpl_overlay`` on and draws the VPLs ``bake.remembered`` holds for the
scene being drawn. The GPU batch is rebuilt only when those VPLs change.
"""
import bpy
from bpy.app.handlers import persistent

from . import bake, bake_math

POINT_SIZE = 6.0
_state = {"handle": None, "source": None, "batch": None, "shader": None}


def update(settings, context):
    """Update callback of ``scene.irad.show_vpl_overlay``."""
    sync()


def is_installed():
    return _state["handle"] is not None


def sync():
    """Install the draw handler while some scene wants it, remove it otherwise."""
    wanted = any(getattr(scene, "irad", None) is not None and scene.irad.show_vpl_overlay
                 for scene in bpy.data.scenes)
    if wanted and _state["handle"] is None:
        _state["handle"] = bpy.types.SpaceView3D.draw_handler_add(
            _draw, (), 'WINDOW', 'POST_VIEW')
    elif not wanted:
        remove()
    redraw()


def remove():
    if _state["handle"] is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_state["handle"], 'WINDOW')
    _state.update(handle=None, source=None, batch=None)


def redraw():
    """Ask every 3D Viewport to redraw (none exist in background mode)."""
    wm = bpy.context.window_manager
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type == 'VIEW_3D':
                area.tag_redraw()


def _shader():
    import gpu
    if _state["shader"] is None:
        try:
            _state["shader"] = gpu.shader.from_builtin('POINT_FLAT_COLOR')
        except ValueError:                      # older names
            _state["shader"] = gpu.shader.from_builtin('FLAT_COLOR')
    return _state["shader"]


def _batch(traced):
    if _state["source"] is not traced:
        from gpu_extras.batch import batch_for_shader
        vpls = traced.vpls
        _state["batch"] = batch_for_shader(
            _shader(), 'POINTS', {"pos": vpls.position.astype("float32"),
                                  "color": bake_math.display_colors(vpls.flux)})
        _state["source"] = traced
    return _state["batch"]


def _draw():
    import gpu
    scene = bpy.context.scene
    if scene is None or not scene.irad.show_vpl_overlay:
        return
    traced = bake.remembered(scene)
    if traced is None or traced.vpls.count == 0:
        return
    batch = _batch(traced)
    gpu.state.point_size_set(POINT_SIZE)
    gpu.state.depth_test_set('LESS_EQUAL')
    _shader().bind()
    batch.draw(_shader())
    gpu.state.depth_test_set('NONE')
    gpu.state.point_size_set(1.0)


@persistent
def _on_load(_dummy):
    """A newly loaded file has no traced VPLs: forget the old ones, re-sync the handler."""
    bake.forget_all()
    sync()


def register():
    bpy.app.handlers.load_post.append(_on_load)


def unregister():
    if _on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_on_load)
    remove()
    bake.forget_all()
    _state["shader"] = None

"""Install and enable the checkout as the extension `bl_ext.user_default.instant_radiosity`
inside a bpy process, in a throw-away Blender user directory (never the user's own).

Blender reads BLENDER_USER_RESOURCES once, when bpy is imported, so the order is:

    from benchmarks import addon_install
    addon_install.prepare_user_resources()   # before `import bpy`
    import bpy
    module = addon_install.enable_extension()

enable_extension() calls prepare_user_resources() itself when bpy is not imported yet.
The add-on must be reached only through the returned module (e.g.
module.irad_addon.render), never as a top-level `irad_addon` from the checkout:
a second copy would hold its own classes and state.
"""
import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ADDON_ID = "instant_radiosity"
ADDON_MODULE = f"bl_ext.user_default.{ADDON_ID}"
ENGINE = "INSTANT_RADIOSITY"

_ENV_MARK = "IRAD_TEMP_USER_RESOURCES"  # set to the temp dir we created


def prepare_user_resources():
    """Point BLENDER_USER_RESOURCES at a fresh temp dir (removed at exit); returns it.
    Idempotent. Must run before `import bpy`."""
    own = os.environ.get(_ENV_MARK)
    if own and os.environ.get("BLENDER_USER_RESOURCES") == own:
        return own
    if "bpy" in sys.modules:
        raise RuntimeError("bpy was imported before prepare_user_resources(): Blender "
                           "would use the real user directory")
    path = tempfile.mkdtemp(prefix="irad-blender-user-")
    os.environ["BLENDER_USER_RESOURCES"] = path
    os.environ[_ENV_MARK] = path
    # Registered before bpy's own atexit hooks, so it runs after them (LIFO).
    # rmtree unlinks the symlink to the checkout, it does not follow it.
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def engine_registered(idname=ENGINE):
    import bpy
    return any(getattr(cls, "bl_idname", None) == idname and cls.is_registered
               for cls in bpy.types.RenderEngine.__subclasses__())


def _raise(ex):
    raise ex


def enable_extension():
    """Link the checkout into the user_default extensions repo (as a dev install
    would) and enable it; returns the add-on module. Raises on any failure."""
    if "bpy" not in sys.modules:
        prepare_user_resources()
    elif os.environ.get("BLENDER_USER_RESOURCES") != os.environ.get(_ENV_MARK):
        raise RuntimeError("call prepare_user_resources() before `import bpy`")
    import embreex  # noqa: F401  (Blender would install the bundled wheel; the venv has it)
    import addon_utils
    import bpy

    repo = Path(bpy.utils.user_resource('EXTENSIONS', path="user_default", create=True))
    link = repo / ADDON_ID
    if not link.exists():
        link.symlink_to(ROOT, target_is_directory=True)
    module = addon_utils.enable(ADDON_MODULE, default_set=True, handle_error=_raise)
    if module is not sys.modules.get(ADDON_MODULE):
        raise RuntimeError(f"{ADDON_MODULE} did not load as expected")
    if Path(module.__file__).parent != link:
        raise RuntimeError(f"{ADDON_MODULE} loaded from {module.__file__}, not {link}")
    if not hasattr(bpy.types.Scene, "irad"):
        raise RuntimeError("register() did not add Scene.irad")
    if not engine_registered():
        raise RuntimeError(f"{ENGINE} is not a registered RenderEngine")
    return module


def disable_extension():
    """Disable the add-on and remove the link enable_extension() made."""
    import addon_utils
    import bpy
    addon_utils.disable(ADDON_MODULE, default_set=True, handle_error=_raise)
    link = Path(bpy.utils.user_resource('EXTENSIONS', path="user_default")) / ADDON_ID
    if link.is_symlink():
        link.unlink()

"""Shared harness: an isolated Blender user dir, the extension linked in and enabled.

Tests reach the add-on only through the `addon` fixture (the module
`bl_ext.user_default.instant_radiosity`), never as top-level `irad_addon`:
a second copy would hold its own classes and state.
"""
import atexit
import importlib.abc
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
ADDON_ID = "instant_radiosity"
ADDON_MODULE = f"bl_ext.user_default.{ADDON_ID}"
ENGINE = "INSTANT_RADIOSITY"

# Must happen before `import bpy`: Blender reads it once at startup.
assert "bpy" not in sys.modules, "bpy was imported before tests/conftest.py"
USER_RESOURCES = tempfile.mkdtemp(prefix="irad-blender-user-")
os.environ["BLENDER_USER_RESOURCES"] = USER_RESOURCES
# Registered before bpy's own atexit hooks, so it runs after them (LIFO).
atexit.register(shutil.rmtree, USER_RESOURCES, ignore_errors=True)

sys.path.insert(0, str(ROOT))  # for `from benchmarks import ...`

import bpy  # noqa: E402
import addon_utils  # noqa: E402


class _BlockCheckoutImports(importlib.abc.MetaPathFinder):
    """The repo root is on sys.path for benchmarks/; keep it from exposing a 2nd add-on copy."""
    NAMES = {"irad_addon", "operators", "panels"}

    def find_spec(self, name, path=None, target=None):
        if path is None and name in self.NAMES:
            raise ImportError(f"import {name!r} through the `addon` fixture "
                              f"(e.g. addon.irad_addon), not from the checkout")
        return None


sys.meta_path.insert(0, _BlockCheckoutImports())


def _raise(ex):
    raise ex


def engine_registered(idname=ENGINE):
    return any(getattr(cls, "bl_idname", None) == idname and cls.is_registered
               for cls in bpy.types.RenderEngine.__subclasses__())


@pytest.fixture(scope="session")
def addon():
    """Link the checkout into the user_default repo (as a dev install would) and enable it."""
    try:
        import embreex  # noqa: F401  (Blender would install the bundled wheel; here the venv has it)
    except ImportError as ex:
        pytest.fail(f"embreex is not importable: {ex}; run `make .venv/.installed`")
    repo = Path(bpy.utils.user_resource('EXTENSIONS', path="user_default", create=True))
    link = repo / ADDON_ID
    if not link.exists():
        link.symlink_to(ROOT, target_is_directory=True)
    module = addon_utils.enable(ADDON_MODULE, default_set=True, handle_error=_raise)
    assert module is sys.modules[ADDON_MODULE]
    assert Path(module.__file__).parent == link, module.__file__
    assert hasattr(bpy.types.Scene, "irad"), "register() did not add Scene.irad"
    assert engine_registered(), f"{ENGINE} is not a registered RenderEngine"
    yield module
    addon_utils.disable(ADDON_MODULE, default_set=True, handle_error=_raise)
    link.unlink()


@pytest.fixture
def scene(addon):
    """An empty scene; read_homefile keeps the add-on registered (factory settings would not)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene

"""Shared harness: an isolated Blender user dir, the extension linked in and enabled.

Tests reach the add-on only through the `addon` fixture (the module
`bl_ext.user_default.instant_radiosity`), never as top-level `irad_addon`:
a second copy would hold its own classes and state.
"""
import importlib.abc
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # for `from benchmarks import ...`

from benchmarks import addon_install  # noqa: E402

# Must happen before `import bpy`: Blender reads BLENDER_USER_RESOURCES once at startup.
assert "bpy" not in sys.modules, "bpy was imported before tests/conftest.py"
addon_install.prepare_user_resources()

import bpy  # noqa: E402


class _BlockCheckoutImports(importlib.abc.MetaPathFinder):
    """The repo root is on sys.path for benchmarks/; keep it from exposing a 2nd add-on copy."""
    NAMES = {"irad_addon", "operators", "panels"}

    def find_spec(self, name, path=None, target=None):
        if path is None and name in self.NAMES:
            raise ImportError(f"import {name!r} through the `addon` fixture "
                              f"(e.g. addon.irad_addon), not from the checkout")
        return None


sys.meta_path.insert(0, _BlockCheckoutImports())


@pytest.fixture(scope="session")
def addon():
    """The checkout linked into the user_default repo (as a dev install) and enabled."""
    try:
        import embreex  # noqa: F401  (Blender would install the bundled wheel; the venv has it)
    except ImportError as ex:
        pytest.fail(f"embreex is not importable: {ex}; run `make .venv/.installed`")
    yield addon_install.enable_extension()
    addon_install.disable_extension()


@pytest.fixture
def scene(addon):
    """An empty scene; read_homefile keeps the add-on registered (factory settings would not)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


@pytest.fixture
def record(monkeypatch):
    """record(owner, name) -> a list that gets the result of every call of owner.name
    (patched for the test), in order."""
    def install(owner, name):
        results, original = [], getattr(owner, name)

        def recording(*args, **kwargs):
            results.append(original(*args, **kwargs))
            return results[-1]
        monkeypatch.setattr(owner, name, recording)
        return results
    return install

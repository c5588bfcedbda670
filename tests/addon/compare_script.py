"""``blender_scripts/compare_render.py`` loaded as a module (it is a script, not a package
member), for the tests that compare Blender's render with the engine's."""

from __future__ import annotations

import importlib.util

from .conftest import REPO


def _load():
    path = REPO / "blender_scripts" / "compare_render.py"
    spec = importlib.util.spec_from_file_location("compare_render", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


CMP = _load()

"""Add-on tests: the ``bpy`` module from PyPI (headless Blender), the add-on enabled once per
module through ``addon_utils`` (so its preferences exist), a fresh startup file per test."""

from __future__ import annotations

from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
import addon_utils  # noqa: E402  (ships with bpy)

REPO = Path(__file__).resolve().parents[2]
ADDON = "blender_addon"


@pytest.fixture(scope="module", autouse=True)
def addon():
    mod = addon_utils.enable(ADDON, default_set=True)
    assert mod is not None, "the add-on failed to enable"
    yield mod
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture(autouse=True)
def fresh_file(addon):
    bpy.ops.wm.read_homefile(app_template="")
    yield


@pytest.fixture(scope="session")
def ribs(tmp_path_factory):
    """The synthetic 2DGS 'ribs' scene (20k surfels, cameras, NeRF grid) on disk."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs")
    generate_scene("ribs", out, size=20_000, seed=0, grid_resolution=48)
    return out

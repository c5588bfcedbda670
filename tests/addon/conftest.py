"""Add-on tests: the ``bpy`` module from PyPI (headless Blender), the add-on enabled once per
module through ``addon_utils`` (so its preferences exist), a fresh startup file per test.

Anchors render at the camera's size × Render Scale (preference ``anchor_resolution`` 0)
unless a test sets it, to keep the suite fast; recovery autosaves go to a temporary
folder instead of the user's Blender folder. Blender's undo runs for real
(``bpy.ops.ed.undo`` / ``ed.redo`` work headless once the stack has its first step)."""

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
def fresh_file(addon, tmp_path_factory, monkeypatch):
    from blender_addon.preferences import ANCHOR_RESOLUTION, get_preferences
    from blender_addon.session_actions import files

    sessions = tmp_path_factory.mktemp("user_sessions")
    monkeypatch.setattr(files, "user_sessions_dir", lambda: sessions)
    bpy.ops.wm.read_homefile(app_template="")
    # headless, the undo stack starts empty after loading a file (a window's starts with
    # the loaded state): the first push is that initial state, so make it here
    bpy.ops.ed.undo_push(message="DivAS test: fresh file")
    prefs = get_preferences()
    prefs.anchor_resolution, prefs.resume_on_open = 0, False
    yield
    # fetched again: a test that unregisters and registers the add-on frees the struct the
    # reference above points to (writing through it crashed Blender now and then)
    prefs = get_preferences()
    prefs.anchor_resolution, prefs.resume_on_open = ANCHOR_RESOLUTION, True


@pytest.fixture(scope="session")
def ribs(tmp_path_factory):
    """The synthetic 2DGS 'ribs' scene (20k surfels, cameras, NeRF grid) on disk."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs")
    generate_scene("ribs", out, size=20_000, seed=0, grid_resolution=48)
    return out


def one_click_prompts(data: Path, capture: str, target: str, path: Path):
    """Write a prompts file of the first hand-placed anchor of ``target`` on the capture
    ``data / capture`` (``tests/data/targets``) with its first click, as a positive click,
    to ``path``; returns the target's ground-truth labels per scene row."""
    from divas_engine import load_scene
    from divas_engine.evaluation.real_targets import (
        oracle_anchors,
        read_targets,
        target_scene_labels,
    )
    from divas_engine.session import Click, Prompts
    from divas_engine.session.prompts import AnchorPrompt

    scene = load_scene(data / capture)
    doc = read_targets(data / "targets" / Path(capture).name.split(".")[0])
    anchors = oracle_anchors(scene, doc["true_up"], doc["targets"][target]["anchors"])
    cam, _, _, clicks = anchors[0]
    Prompts((AnchorPrompt("camera", cam, (Click(clicks[0], positive=True),)),)).write(path)
    return target_scene_labels(scene, doc, target)

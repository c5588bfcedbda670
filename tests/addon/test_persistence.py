"""The session follows the .blend — session → click → accept → rename →
Save As (twice, to other folders) → reopen → resume: same selection, the anchor images
intact (packed), the cameras kept, the scene path relative; the one-click and the
automatic resume; an unsaved file's sessions apart per object."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge, session_registry, source
from blender_addon.preferences import get_preferences
from blender_addon.session_actions import files, saved_session_path
from blender_addon.session_registry import KEY_PROP
from divas_engine.point_attributes import INDEX, SELECTED, scene_selection

SCALE = 0.5


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_files")
    sc = generate_scene("ribs", out, size=8000, seed=3, grid_resolution=24)
    return out, sc


def _start(scene_dir, autosave=False):
    out, _ = scene_dir
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = autosave
    assert bpy.ops.divas.start_session(
        segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy")
    ) == {"FINISHED"}
    return obj, session_registry.get(obj)


def _click(live, i, sc):
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            xy = f"{float(uv[0, 0])!r} {float(uv[0, 1])!r}"
            assert bpy.ops.divas.session_click(anchor=i, xy=xy) == {"FINISHED"}
            return
    pytest.skip("no click point visible")


def _resume(out):
    gt = str(out / "labels.npy")
    return bpy.ops.divas.resume_session(segmenter="oracle", device="cpu", gt_labels=gt)


def _pixels(img) -> np.ndarray:
    px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(px)
    return px


def _anchor_images(names, packed: bool = True) -> dict[str, np.ndarray]:
    out = {}
    for n in names:
        img = bpy.data.objects[n].data.background_images[0].image
        assert (img.packed_file is not None) == packed, n
        out[n] = _pixels(img)
    return out


def test_save_as_reopen_resume(scene_dir, tmp_path):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    key = obj[KEY_PROP]
    _click(live, 0, sc)
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    _click(live, 1, sc)  # an open view is part of the saved state too
    sel = live.session.selection.copy()
    assert sel.sum() > 50
    all_anchors = list(live.anchor_cameras)
    # anchors render lazily: the ones looked through or clicked have their
    # render packed; the others have no image (made when first looked through)
    anchors = [n for n, a in zip(all_anchors, live.session.anchors) if a.rendered]
    assert len(anchors) >= 2
    for n in set(all_anchors) - set(anchors):
        assert len(bpy.data.objects[n].data.background_images) == 0
    # packed at the next idle moment (no event loop here) or, at the latest, by the save
    images = _anchor_images(anchors, packed=False)
    for n, a in zip(anchors, live.session.anchors):  # the images are the engine's renders
        ref = np.clip(a.rgb, 0, 1)[::-1].reshape(-1, 3)
        np.testing.assert_allclose(images[n].reshape(-1, 4)[:, :3], ref, atol=1 / 254)
    # rename the object, Save As twice, to two folders
    obj.name = "skull"
    first = tmp_path / "a" / "shot.blend"
    first.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(first))
    assert files.sidecar_path(first, key).is_file()
    assert _anchor_images(anchors).keys() == images.keys()  # packed by save_pre
    obj = bpy.data.objects["skull"]
    assert str(obj[source.PATH_PROP]).startswith("//")  # relative to the .blend
    assert source.source_of(obj).path.resolve() == (out / "scene.ply").resolve()
    assert bpy.ops.divas.session_accept() == {"FINISHED"}  # a later change …
    second = tmp_path / "b" / "renamed.blend"
    second.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(second))
    live2 = session_registry.get(bpy.data.objects["skull"])
    sel2 = live2.session.selection.copy()
    views = sorted(live2.view_cameras.values())  # an accept may add wider views' cameras
    assert sel2.sum() > sel.sum()
    assert files.sidecar_path(second, key).is_file()
    obj = bpy.data.objects["skull"]
    assert source.source_of(obj).path.resolve() == (out / "scene.ply").resolve()
    # reopen the second file: the session is gone until resumed; the images are intact
    bpy.ops.wm.open_mainfile(filepath=str(second))
    assert session_registry.all_sessions() == []
    obj = bpy.data.objects["skull"]
    assert saved_session_path(obj) == files.sidecar_path(second, key)
    reopened = _anchor_images(anchors)
    for n in anchors:
        np.testing.assert_array_equal(reopened[n], images[n])
    n_objects = len(bpy.data.objects)
    bpy.context.view_layer.objects.active = obj
    assert _resume(out) == {"FINISHED"}
    live = session_registry.get(obj)
    assert live.session.replay_matches and live.key == key
    np.testing.assert_array_equal(live.session.selection, sel2)
    mapped = scene_selection(
        live.session.scene,
        bridge.read_attribute(obj.data, INDEX),
        bridge.read_attribute(obj.data, SELECTED),
    )
    np.testing.assert_array_equal(mapped, sel2)
    # the file's cameras were kept (not made again), their images untouched
    assert live.anchor_cameras == all_anchors and len(bpy.data.objects) == n_objects
    assert sorted(live.view_cameras.values()) == views
    for n, px in _anchor_images(anchors).items():
        np.testing.assert_array_equal(px, images[n])
    # the first file's sidecar still holds the state of that save
    bpy.ops.wm.open_mainfile(filepath=str(first))
    obj = bpy.data.objects["skull"]
    bpy.context.view_layer.objects.active = obj
    assert _resume(out) == {"FINISHED"}
    np.testing.assert_array_equal(session_registry.get(obj).session.selection, sel)


def test_resume_on_open(scene_dir, tmp_path, monkeypatch):
    """With "Resume Sessions on Open", opening the .blend resumes its sessions (the
    ``load_post`` handler schedules it; headless timers do not run, so the scheduled
    function is called here)."""
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    _click(live, 0, sc)
    bpy.ops.divas.session_accept()
    sel = live.session.selection.copy()
    path = tmp_path / "auto.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    scheduled = []
    monkeypatch.setattr(bpy.app.timers, "register", lambda fn, **kw: scheduled.append(fn))
    get_preferences().resume_on_open = True
    bpy.ops.wm.open_mainfile(filepath=str(path))
    assert scheduled and session_registry.all_sessions() == []
    # resume with the preferences' segmenter (classic): the saved masks replay as they were
    scheduled[0]()
    (live,) = session_registry.all_sessions()
    assert live.session.replay_matches
    np.testing.assert_array_equal(live.session.selection, sel)


def test_unsaved_sessions_autosave_apart(scene_dir):
    """Two unsaved files whose objects have the same name autosave to two recovery
    files; a recovered object finds its own."""
    out, sc = scene_dir
    paths = []
    for _ in range(2):
        bpy.ops.wm.read_homefile(app_template="")
        obj, live = _start(scene_dir, autosave=True)
        _click(live, 0, sc)
        bpy.ops.divas.session_accept()
        paths.append(live.autosave)
        assert paths[-1] == files.recovery_path(obj[KEY_PROP]) and paths[-1].is_file()
        assert saved_session_path(obj) == paths[-1]  # no .blend: the recovery file
    assert paths[0] != paths[1] and paths[0].parent == files.user_sessions_dir()

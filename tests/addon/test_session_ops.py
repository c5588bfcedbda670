"""Start DivAS (anchor cameras with exact projections and their
renders as background images), the EXEC session operators against the engine Session
(click, accept → ``divas_selected``, undo, finish object → ``divas_label``, reset),
autosave + resume, export/extract after a session, errors as one-line reports, the
panel and the scene settings."""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import plyfile
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from blender_addon import bridge, session_registry
from blender_addon.camera_objects import apply_render_settings
from blender_addon.modal_logic import ANCHOR_PROP, OWNER_PROP, VIEW_PROP
from blender_addon.overlays import image_name
from blender_addon.properties import session_config
from blender_addon.session_actions import LABEL_ATTRIBUTE, VIEWS_COLLECTION, autosave_path, files
from blender_addon.session_registry import KEY_PROP
from divas_engine.point_attributes import INDEX, SELECTED, point_values, scene_selection
from divas_engine.session import SessionConfig

SCALE = 0.5


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    """A small synthetic 2DGS scene (15k surfels), its cameras, labels and click points."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_ops")
    sc = generate_scene("ribs", out, size=15_000, seed=0, grid_resolution=32)
    return out, sc


def _start(scene_dir, tmp_path=None, **kw):
    out, _ = scene_dir
    assert bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"), display=True) == {
        "FINISHED"
    }
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = SCALE
    kw.setdefault("device", "cpu")
    if tmp_path is not None:
        kw.setdefault("autosave", str(tmp_path / "session.json"))
    else:
        bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(**kw) == {"FINISHED"}
    return obj, session_registry.get(obj)


def _oracle(scene_dir, tmp_path=None):
    out, _ = scene_dir
    return _start(scene_dir, tmp_path, segmenter="oracle", gt_labels=str(out / "labels.npy"))


def _click_xy(live, i, sc, k=0):
    """Pixel of metadata click ``k`` in anchor ``i`` (the first click visible there)."""
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"][k:] + sc.metadata["clicks"][:k]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            return float(uv[0, 0]), float(uv[0, 1])
    pytest.skip("no click point visible in this anchor")


def _image_rgb(img) -> np.ndarray:
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1, :, :3]


def _projection_error(scene, cam_obj, engine_cam, rng) -> float:
    apply_render_settings(scene, cam_obj)
    bpy.context.view_layer.update()
    uv = rng.uniform([0, 0], [engine_cam.width, engine_cam.height], (40, 2))
    pts = engine_cam.unproject(uv, rng.uniform(0.5, 5.0, 40))
    # scene-frame points into the world through the object the camera is parented to
    # (an import puts its axis conversion on the object)
    m = np.array(cam_obj.parent.matrix_world) if cam_obj.parent is not None else np.eye(4)
    world = pts @ m[:3, :3].T + m[:3, 3]
    w, h = scene.render.resolution_x, scene.render.resolution_y
    got = np.array([world_to_camera_view(scene, cam_obj, Vector(p))[:2] for p in world])
    got = np.stack([got[:, 0] * w, (1.0 - got[:, 1]) * h], axis=1)
    expect, _ = engine_cam.project(pts)
    return float(np.abs(got - expect).max())


def _selection_matches(obj, live) -> None:
    geom = obj.data
    mapped = scene_selection(
        live.session.scene,
        bridge.read_attribute(geom, INDEX),
        bridge.read_attribute(geom, SELECTED),
    )
    np.testing.assert_array_equal(mapped, live.session.selection)


def test_start_session_cameras_images_projection(scene_dir):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    s = live.session
    assert live is not None and s.kind == "2dgs" and len(s.scene) == len(sc.scene)
    assert s.config.render_scale == SCALE and s.config.autosave is None
    coll = bpy.data.collections[VIEWS_COLLECTION]
    assert coll.name in bpy.context.scene.collection.children
    cams = [bpy.data.objects[n] for n in live.anchor_cameras]
    assert len(cams) == len(s.anchors) >= 3 and all(c.name in coll.objects for c in cams)
    # the first anchor is the scene camera, with its own render size
    assert bpy.context.scene.camera == cams[0]
    r = bpy.context.scene.render
    assert (r.resolution_x, r.resolution_y) == (
        s.anchors[0].camera.width,
        s.anchors[0].camera.height,
    )
    rng = np.random.default_rng(0)
    # anchors render lazily: the first at Start, each other one when first
    # looked through (Look Through Camera here), then with its render behind it
    assert [a.rendered for a in s.anchors] == [True] + [False] * (len(s.anchors) - 1)
    for i, (cam, a) in enumerate(zip(cams, s.anchors)):
        assert cam[OWNER_PROP] == obj.name and cam[ANCHOR_PROP] == i and cam.parent == obj
        assert tuple(cam["divas_resolution"]) == (a.camera.width, a.camera.height)
        if i > 0:
            assert len(cam.data.background_images) == 0
            bpy.context.view_layer.objects.active = cam
            assert bpy.ops.divas.activate_camera() == {"FINISHED"}
            assert a.rendered
        assert cam.data.show_background_images and len(cam.data.background_images) == 1
        bg = cam.data.background_images[0]
        assert bg.image.name == image_name(cam) and tuple(bg.image.size) == (
            a.camera.width,
            a.camera.height,
        )
        assert bg.frame_method == "STRETCH"
        bridge.pack_pending()  # what the idle timer does (no event loop runs here)
        assert bg.image.packed_file is not None
        np.testing.assert_allclose(_image_rgb(bg.image), np.clip(a.rgb, 0, 1), atol=1.0 / 254)
        assert _projection_error(bpy.context.scene, cam, a.camera, rng) < 0.5
    # a centroid view's camera is exact too
    assert bpy.ops.divas.session_click(
        anchor=1, xy="{!r} {!r}".format(*_click_xy(live, 1, sc))
    ) == {"FINISHED"}
    v = s.views[-1]
    vcam = bpy.context.scene.camera
    assert vcam[VIEW_PROP] == v.id and vcam.name in coll.objects and vcam.parent == obj
    assert tuple(vcam.data.background_images[0].image.size) == (v.camera.width, v.camera.height)
    assert _projection_error(bpy.context.scene, vcam, v.camera, rng) < 0.5
    # its own near clip (a fraction of the orbit radius) carried to the Blender camera
    s_obj = abs(np.linalg.det(np.array(obj.matrix_world)[:3, :3])) ** (1 / 3)
    assert v.camera.near > 0.01
    assert vcam.data.clip_start == pytest.approx(v.camera.near * s_obj, rel=1e-5)
    assert v.preview is not None  # the default prompt was previewed
    assert live.last_update["what"] == f"view {v.id}" and live.last_update["update_s"] > 0


def test_scene_settings_defaults_are_the_engine_defaults():
    props = bpy.context.scene.divas
    assert session_config(props) == SessionConfig(render_scale=0.5)
    props.see_through_gap, props.surfel_coverage, props.gamma = 2.0, 0.3, 1.7
    props.preset, props.render_scale = "FORWARD", 0.3
    cfg = session_config(props, autosave="/tmp/x.json")
    assert (cfg.gs_fusion.gamma_st, cfg.mapping.surfel_coverage, cfg.gs_fusion.gamma) == (
        2.0,
        0.3,
        1.7,
    )
    assert cfg.render_scale == 0.3 and cfg.grid.g_max == 512 and cfg.nerf_preset == "llff"
    assert cfg.autosave == "/tmp/x.json"
    # NeRF Views: Auto (by device), Network, Grid
    for item, want in (("NETWORK", True), ("GRID", False), ("AUTO", None)):
        props.nerf_views = item
        assert session_config(props).render.nerf_network is want


def test_click_accept_undo_finish_reset(scene_dir, tmp_path):
    out, sc = scene_dir
    obj, live = _oracle(scene_dir, tmp_path)
    s = live.session
    auto = tmp_path / "session.json"
    assert bpy.ops.divas.session_click(
        anchor=0, xy="{!r} {!r}".format(*_click_xy(live, 0, sc))
    ) == {"FINISHED"}
    v0 = s.views[0]
    assert bpy.context.scene.camera.name == live.view_cameras[v0.id]
    assert auto.is_file()  # autosaved from the open on, and after every click
    # accept the scene camera's view
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    assert v0.status == "fused" and s.selection.sum() > 100
    _selection_matches(obj, live)
    labels = bridge.read_attribute(obj.data, LABEL_ATTRIBUTE)
    np.testing.assert_array_equal(
        labels, bridge.read_attribute(obj.data, SELECTED).astype(np.int32)
    )
    assert auto.is_file()  # autosaved after the accept
    assert {"kernel_s", "mapping_s", "update_s"} <= set(live.last_update)
    # back on the anchor (no other open view), showing the selection
    assert bpy.context.scene.camera.name == live.anchor_cameras[0]
    sel0 = s.selection.copy()
    # a second view, with an extra negative point given as JSON
    assert bpy.ops.divas.session_click(
        anchor=1, xy="{!r} {!r}".format(*_click_xy(live, 1, sc, 1)), preview=False
    ) == {"FINISHED"}
    v1 = s.views[1]
    assert v1.preview is None
    assert bpy.ops.divas.session_accept(view=v1.id, points="[[1.5, 1.5, false]]") == {"FINISHED"}
    assert v1.labels.tolist()[-1] == 0 and v1.points[-1].tolist() == [1.5, 1.5]
    _selection_matches(obj, live)
    # undo: exact
    assert bpy.ops.divas.session_undo() == {"FINISHED"}
    assert v1.status == "open" and np.array_equal(s.selection, sel0)
    _selection_matches(obj, live)
    assert bpy.context.scene.camera.name == live.view_cameras[v1.id]
    # finish object: label 1 on the points, selection cleared, the open view's camera gone
    assert bpy.ops.divas.session_finish_object(name="skull") == {"FINISHED"}
    labels = bridge.read_attribute(obj.data, LABEL_ATTRIBUTE)
    np.testing.assert_array_equal(
        labels == 1, point_values(s.scene, bridge.read_attribute(obj.data, INDEX), sel0)
    )
    assert not bridge.read_attribute(obj.data, SELECTED).any()
    assert (
        v1.id not in live.view_cameras and bpy.data.objects.get(f"{obj.name} View {v1.id}") is None
    )
    # multi-object export: one PLY per finished object + the labelled PLY
    exp = tmp_path / "objects"
    assert bpy.ops.divas.export_objects(directory=str(exp)) == {"FINISHED"}
    obj_files = sorted(exp.glob("01_*.ply"))
    assert len(obj_files) == 1 and (exp / "labelled.ply").is_file()
    lab = plyfile.PlyData.read(str(exp / "labelled.ply"))["vertex"].data["divas_label"]
    np.testing.assert_array_equal(lab, s.label_set())
    assert len(plyfile.PlyData.read(str(obj_files[0]))["vertex"].data) == int(sel0.sum())
    # reset everything
    assert bpy.ops.divas.session_reset(all_objects=True) == {"FINISHED"}
    assert not bridge.read_attribute(obj.data, LABEL_ATTRIBUTE).any()
    assert live.view_cameras == {} and s.undo() is None
    assert bpy.ops.divas.session_undo() == {"CANCELLED"}  # a warning: "Nothing to undo"


def test_autosave_path_is_unique_per_object(tmp_path):
    """Between saves a session autosaves to a recovery file keyed by the object's own
    session key: two objects of the same name (two unsaved files) never collide."""
    obj = bpy.data.objects["Cube"]
    first = autosave_path(obj)
    assert first.parent == files.user_sessions_dir() and first.stem == obj[KEY_PROP]
    assert autosave_path(obj) == first  # stable
    bpy.ops.wm.read_homefile(app_template="")
    other = bpy.data.objects["Cube"]  # same name, another file
    assert autosave_path(other) != first
    dup = other.copy()  # a duplicate carries the key: it gets its own
    bpy.context.scene.collection.objects.link(dup)
    assert autosave_path(dup) != autosave_path(other)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    assert files.sidecar_path(bpy.data.filepath, "k") == tmp_path / "shot.divas" / "k.json"


def test_resume_session(scene_dir, tmp_path):
    out, sc = scene_dir
    obj, live = _oracle(scene_dir, tmp_path)
    bpy.ops.divas.session_click(anchor=0, xy="{!r} {!r}".format(*_click_xy(live, 0, sc)))
    bpy.ops.divas.session_accept()
    bpy.ops.divas.session_click(anchor=2, xy="{!r} {!r}".format(*_click_xy(live, 2, sc, 2)))
    sel = live.session.selection.copy()
    n_anchors = len(live.session.anchors)
    # a new file: the session is closed and forgotten
    bpy.ops.wm.read_homefile(app_template="")
    assert session_registry.all_sessions() == []
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    assert bpy.ops.divas.resume_session(
        filepath=str(tmp_path / "session.json"),
        segmenter="oracle",
        device="cpu",
        gt_labels=str(out / "labels.npy"),
    ) == {"FINISHED"}
    live = session_registry.get(obj)
    assert live.session.replay_matches and np.array_equal(live.session.selection, sel)
    assert len(live.anchor_cameras) == n_anchors
    assert set(live.view_cameras) == {v.id for v in live.session.views}
    _selection_matches(obj, live)
    # it autosaves to the object's recovery file from now on
    assert live.session.config.autosave == str(files.recovery_path(obj[KEY_PROP]))


def test_export_and_extract_after_session(scene_dir, tmp_path):
    out, sc = scene_dir
    obj, live = _oracle(scene_dir)
    for i in range(2):
        bpy.ops.divas.session_click(anchor=i, xy="{!r} {!r}".format(*_click_xy(live, i, sc, i)))
        bpy.ops.divas.session_accept()
    ours, ref = tmp_path / "ours.ply", tmp_path / "engine.ply"
    assert bpy.ops.divas.export_selection(filepath=str(ours), write_labels=True) == {"FINISHED"}
    res = live.session.export(ref, labels_path=tmp_path / "engine_labels.npy")
    assert res.count == live.session.selection.sum() > 0
    assert ours.read_bytes() == ref.read_bytes()
    np.testing.assert_array_equal(
        np.load(tmp_path / "ours_labels.npy"), np.load(tmp_path / "engine_labels.npy")
    )
    assert bpy.ops.divas.extract_selection() == {"FINISHED"}
    new = bpy.context.active_object
    assert new != obj and len(new.data.points) == res.count


def test_errors_are_one_line_reports(scene_dir, tmp_path):
    out, sc = scene_dir
    assert not bpy.ops.divas.start_session.poll()  # the cube is not an imported scene
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    bpy.context.scene.divas.autosave = False
    with pytest.raises(RuntimeError, match="oracle segmenter needs") as e:
        bpy.ops.divas.start_session(segmenter="oracle", device="cpu")
    assert "Traceback" not in str(e.value)
    with pytest.raises(RuntimeError, match="prompts file not found"):
        bpy.ops.divas.start_session(device="cpu", prompts=str(tmp_path / "nope.json"))
    assert session_registry.get(bpy.context.active_object) is None
    assert not bpy.ops.divas.session_click.poll()
    obj, live = _start(scene_dir)
    with pytest.raises(RuntimeError, match="outside"):
        bpy.ops.divas.session_click(anchor=0, x=-5.0, y=3.0)
    with pytest.raises(RuntimeError, match=r"no anchor 99 \(this session has \d+"):
        bpy.ops.divas.session_click(anchor=99, x=5.0, y=3.0)
    with pytest.raises(RuntimeError, match="no open view to accept: click the object"):
        bpy.ops.divas.session_accept()
    with pytest.raises(RuntimeError, match="Points must be JSON"):
        bpy.ops.divas.session_accept(points="[oops")
    with pytest.raises(RuntimeError, match="no saved DivAS session"):
        bpy.ops.divas.resume_session(filepath=str(tmp_path / "missing.json"), device="cpu")


def test_segmenter_errors_come_from_the_engine_and_say_where(scene_dir):
    """The engine's setup error, with where the add-on's user sets what is missing."""
    out, _ = scene_dir
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    bpy.context.scene.divas.autosave = False
    msg = r"SAM \(ONNX\) segmenter needs the encoder and decoder.*add-on preferences"
    with pytest.raises(RuntimeError, match=msg):
        bpy.ops.divas.start_session(segmenter="sam-onnx", device="cpu")
    with pytest.raises(RuntimeError, match=r"SAM \(PyTorch\).*add-on preferences"):
        bpy.ops.divas.start_session(segmenter="sam-torch", device="cpu")
    assert session_registry.get(bpy.context.active_object) is None


def test_full_resolution_click_uses_the_engine_range_and_scale(scene_dir):
    obj, live = _start(scene_dir)
    a = live.session.anchors[0]
    with pytest.raises(RuntimeError, match="no anchor 99"):
        bpy.ops.divas.session_click(anchor=99, xy="5 3", full_resolution=True)
    x, y = a.full_camera.width * 0.5 + 0.25, a.full_camera.height * 0.5 + 0.25
    assert bpy.ops.divas.session_click(anchor=0, xy=f"{x!r} {y!r}", full_resolution=True) == {
        "FINISHED"
    }
    click = live.session.current.clicks[0][-1]
    assert click.xy == (
        x * (a.camera.width / a.full_camera.width),
        y * (a.camera.height / a.full_camera.height),
    )


class _Layout:
    """Records what a panel draws (headless Blender has no UI to draw into)."""

    def __init__(self, log):
        self.log = log
        self.use_property_split = False
        self.active = True
        self.scale_y = 1.0

    def _child(self, *a, **k):
        return _Layout(self.log)

    box = column = row = _child

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text))

    def operator(self, idname, text="", icon="NONE"):
        self.log.append(("operator", idname))
        return SimpleNamespace()

    def prop(self, data, name, **k):
        getattr(data, name)
        self.log.append(("prop", name))


def test_a_refused_view_says_its_click_stays_selected(scene_dir):
    """A view refused at accept (here: its only prompt negative) keeps the spot its click
    was made on selected (corrections on, the default): the accept's report and the
    panel say so."""
    from blender_addon.operators.session_accept import accept_message

    out, sc = scene_dir
    obj, live = _oracle(scene_dir)
    s = live.session
    xy = _click_xy(live, 0, sc)
    assert bpy.ops.divas.session_click(anchor=0, xy="{!r} {!r}".format(*xy)) == {"FINISHED"}
    v = s.views[0]
    res = s.accept(v, points=[xy], labels=[0], include_default=False)
    assert v.status == "rejected" and s.selection.any() and s.click_holds(v)
    level, text = accept_message(live, res)
    assert level == {"WARNING"} and "The spot you clicked stays selected" in text
    log = []
    bpy.types.DIVAS_PT_main.draw(type("P", (), {"layout": _Layout(log)})(), bpy.context)
    assert any("stays selected" in t for k, t in log if k == "label")


def test_panel_draws_session(scene_dir):
    out, sc = scene_dir
    panel_cls = bpy.types.DIVAS_PT_main
    obj, live = _start(scene_dir)
    bpy.ops.divas.session_click(anchor=0, xy="{!r} {!r}".format(*_click_xy(live, 0, sc)))
    log = []
    panel_cls.draw(type("P", (), {"layout": _Layout(log)})(), bpy.context)
    ops = {v for k, v in log if k == "operator"}
    assert {
        "divas.start_session",
        "divas.segment_modal",
        "divas.session_accept",
        "divas.session_undo",
        "divas.session_reset",
        "divas.session_finish_object",
        "divas.session_add_anchor",
        "divas.extract_selection",
        "divas.export_selection",
        "divas.resume_session",
        "ed.undo",
        "ed.redo",
        "divas.select_gesture",
        "divas.select_sphere",
        "divas.select_all",
        "divas.select_grow",
        "divas.select_by_attribute",
        "divas.delete_selected",
        "divas.hide_selected",
        "divas.reveal_hidden",
        "divas.separate_selected",
    } <= ops
    props = {v for k, v in log if k == "prop"}
    assert {"device", "segmenter", "preset", "see_through_gap", "surfel_coverage", "gamma"} <= props
    labels = " ".join(v for k, v in log if k == "label")
    assert "2DGS" in labels and "anchors" in labels and "Total:" in labels


def test_restart_replaces_the_session_and_its_cameras(scene_dir):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    bpy.ops.divas.session_click(anchor=0, xy="{!r} {!r}".format(*_click_xy(live, 0, sc)))
    coll = bpy.data.collections[VIEWS_COLLECTION]
    assert len(coll.objects) == len(live.session.anchors) + 1
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.divas.start_session(device="cpu") == {"FINISHED"}
    new = session_registry.get(obj)
    assert new is not live and live.session._closed  # noqa: SLF001
    assert session_registry.all_sessions() == [new]
    assert sorted(o.name for o in coll.objects) == sorted(new.anchor_cameras)
    assert not any(i.name.startswith(f"DivAS {obj.name} View") for i in bpy.data.images)


def test_add_camera_as_anchor(scene_dir):
    """Manual anchor selection: a training camera (and a free camera of a moved object)
    becomes an anchor in the session's scene frame, with its own anchor camera."""
    out, sc = scene_dir
    obj, live = _oracle(scene_dir)
    s = live.session
    n0 = len(s.anchors)
    assert bpy.ops.divas.import_cameras(filepath=str(out / "cameras.json")) == {"FINISHED"}
    train = [o for o in bpy.data.collections["DivAS Cameras"].objects if o.type == "CAMERA"]
    k = len(train) // 2
    assert bpy.ops.divas.session_add_anchor(camera=train[k].name) == {"FINISHED"}
    a = s.anchors[n0]
    assert (a.source, a.source_index) == ("training", k)
    ref_cam = next(c for c in sc.cameras if c.name == train[k].name)
    np.testing.assert_allclose(a.full_camera.c2w, ref_cam.c2w, atol=1e-5)
    assert (a.full_camera.width, a.full_camera.height) == (ref_cam.width, ref_cam.height)
    assert a.full_camera.fx == pytest.approx(ref_cam.fx, rel=1e-5)
    cam = bpy.data.objects[live.anchor_cameras[n0]]
    assert cam[ANCHOR_PROP] == n0 and cam.parent == obj and bpy.context.scene.camera == cam
    assert _projection_error(bpy.context.scene, cam, a.camera, np.random.default_rng(1)) < 0.5
    # the new anchor is clickable like the planned ones
    sel0 = s.selection.copy()
    assert bpy.ops.divas.session_click(
        anchor=n0, xy="{!r} {!r}".format(*_click_xy(live, n0, sc))
    ) == {"FINISHED"}
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    assert s.views[-1].anchor == n0 and s.selection.sum() > sel0.sum()
    # a moved object: a free world-space camera is converted into the scene frame
    obj.location = (0.3, -0.2, 0.5)
    obj.rotation_euler = (0.1, 0.2, 0.3)
    bpy.context.view_layer.update()
    cam0 = bpy.data.objects[live.anchor_cameras[0]]
    free = cam0.copy()
    free.data = cam0.data.copy()
    for key in list(free.keys()):
        del free[key]
    free.parent = None
    bpy.context.scene.collection.objects.link(free)
    free.matrix_world = cam0.matrix_world.copy()
    apply_render_settings(bpy.context.scene, cam0)  # the scene's render size = anchor 0's
    bpy.context.view_layer.update()
    assert bpy.ops.divas.session_add_anchor(camera=free.name) == {"FINISHED"}
    b = s.anchors[-1]
    assert b.source == "camera" and b.source_index == -1
    np.testing.assert_allclose(b.full_camera.c2w, s.anchors[0].camera.c2w, atol=1e-5)
    assert b.full_camera.fx == pytest.approx(s.anchors[0].camera.fx, rel=1e-5)
    # errors are one-line reports
    n = len(s.anchors)
    with pytest.raises(RuntimeError, match="Select a camera object first") as e:
        bpy.ops.divas.session_add_anchor(camera=obj.name)
    assert "Traceback" not in str(e.value)
    with pytest.raises(RuntimeError, match="already one of this session's anchor"):
        bpy.ops.divas.session_add_anchor(camera=cam.name)
    obj.scale = (1.0, 2.0, 1.0)
    bpy.context.view_layer.update()
    with pytest.raises(RuntimeError, match="non-uniform scale"):
        bpy.ops.divas.session_add_anchor(camera=train[0].name)
    assert len(s.anchors) == n


def test_click_on_an_accepted_view_corrects_at_once(scene_dir):
    """Click Anchor with ``view`` on an accepted view, negative: the spot
    leaves the points' selection in the same step, the panel says how many views the
    click changed, one Blender undo step restores the selection exactly."""
    out, sc = scene_dir
    panel_cls = bpy.types.DIVAS_PT_main
    obj, live = _oracle(scene_dir)
    name, s = obj.name, live.session
    undo = ("EXEC_DEFAULT", True)  # each operator one Blender undo step, as from the UI
    xy = "{!r} {!r}".format(*_click_xy(live, 0, sc))
    assert bpy.ops.divas.session_click(*undo, anchor=0, xy=xy) == {"FINISHED"}
    v = s.views[0]
    assert bpy.ops.divas.session_accept(*undo) == {"FINISHED"} and v.status == "fused"
    before = s.selection.copy()
    uv, _ = v.camera.project(v.centroid.target[None])
    uv += 3.0  # beside the view's own prompt: the view takes the click too
    assert bpy.ops.divas.session_click(
        *undo, view=v.id, xy="{!r} {!r}".format(*map(float, uv[0])), positive=False
    ) == {"FINISHED"}
    res = s.last_correction
    assert res.correction.source.view == v.id and before[res.correction.patch].any()
    assert res.resegmented == [v.id] and v.labels.tolist()[-1] == 0
    assert not s.selection[res.correction.patch].any()
    _selection_matches(obj, live)  # written in the same step
    assert live.last_update["views_changed"] == res.views_changed
    log = []
    panel_cls.draw(type("P", (), {"layout": _Layout(log)})(), bpy.context)
    labels = [v for k, v in log if k == "label"]
    assert f"    Views changed: {res.views_changed}" in labels
    assert bpy.ops.ed.undo() == {"FINISHED"}
    np.testing.assert_array_equal(s.selection, before)
    _selection_matches(bpy.data.objects[name], live)
    # a view that does not exist: one line
    with pytest.raises(RuntimeError, match="no view 'nope'"):
        bpy.ops.divas.session_click(view="nope", xy="1 1")

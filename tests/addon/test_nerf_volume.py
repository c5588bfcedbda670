"""NeRF grids in Blender: Import › NeRF as a Volume with the snapshot's cameras, a DivAS
session on it, the segmented part as a new Volume, and exports in the input's format."""

from __future__ import annotations

import numpy as np
import pytest

from blender_addon import bridge, nerf_volume, session_registry, source
from blender_addon.camera_objects import engine_camera
from divas_engine import load_scene
from divas_engine.io.instant_ngp import read_ngp_document, write_ngp_document
from divas_engine.io.openvdb_grid import openvdb_module, read_vdb
from divas_engine.point_attributes import SELECTED
from divas_engine.synthetic.ngp_snapshot import sample_grid, snapshot_of_grid

bpy = pytest.importorskip("bpy")
#: reading a .vdb back needs an OpenVDB module (writing one does not)
HAS_VDB = openvdb_module() is not None


@pytest.fixture(autouse=True)
def volumes_in_tmp(tmp_path_factory, monkeypatch):
    """The volumes' .vdb files go to a temporary folder, not the user's Blender folder."""
    folder = tmp_path_factory.mktemp("volumes")
    monkeypatch.setattr(nerf_volume, "volume_dir", lambda: folder)


@pytest.fixture(scope="module")
def ribs_ngp(tmp_path_factory):
    """The ribs grid (32 cells) as instant-ngp snapshots with and without a network, its
    ground truth on the snapshot's lattice, and the scene."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_ngp")
    sc = generate_scene("ribs", out, size=8_000, seed=0, grid_resolution=32)
    cams = sc.cameras[:6]
    net = out / "ribs_net.ingp"
    write_ngp_document(net, snapshot_of_grid(sc.grid, cams, network_resolution=40), True)
    bare = out / "ribs.ingp"
    write_ngp_document(bare, snapshot_of_grid(sc.grid, cams, network=False), True)
    g = load_scene(bare)
    idx = np.argwhere(np.ones(g.density.shape, bool))[:, ::-1]
    centres = g.aabb[0] + (idx + 0.5) * g.voxel_size
    lab = sample_grid(sc.grid, centres, sc.grid_labels.astype(np.float32), order=0)
    np.save(out / "labels_ngp.npy", (lab.reshape(g.density.shape) > 0.5) & (g.density > 0))
    return out, sc


def _import(path, **kw):
    assert bpy.ops.divas.import_density_grid(filepath=str(path), **kw) == {"FINISHED"}
    return bpy.context.active_object


def test_import_as_volume_with_the_snapshot_cameras(ribs_ngp):
    out, sc = ribs_ngp
    obj = _import(out / "ribs_net.ingp")
    assert obj.type == "POINTCLOUD" and source.source_of(obj).format == "ingp"
    assert obj.display_type == "BOUNDS" and obj.hide_render
    vol = nerf_volume.display_volume_of(obj)
    assert vol is not None and vol.hide_select and vol.parent == obj
    vol.data.grids.load()
    names = {g.name for g in vol.data.grids}
    assert {"density", "color"} <= names  # colour baked from the network
    assert vol.data.materials[0].name == nerf_volume.MATERIAL
    # the volume's density is the grid's, where the grid is
    if HAS_VDB:
        grid = load_scene(out / "ribs_net.ingp")
        back = read_vdb(vol.data.filepath)
        assert int((back.density > 0).sum()) == int((grid.density > 0).sum())
    # the training cameras come in, in the grid's frame
    coll = bpy.data.collections["DivAS Cameras"]
    cams = [o for o in coll.objects if o.type == "CAMERA"]
    assert len(cams) == 6
    for o, c in zip(cams, sc.cameras[:6]):
        e = engine_camera(bpy.context.scene, o)
        np.testing.assert_allclose(e.c2w, c.c2w, atol=1e-4)
        assert (e.width, e.height) == (c.width, c.height)


def test_points_display_stays_an_option(ribs_ngp):
    out, _ = ribs_ngp
    obj = _import(out / "ribs.ingp", display_as="POINTS")
    assert nerf_volume.display_volume_of(obj) is None
    assert obj.display_type != "BOUNDS" and not obj.hide_render


def test_session_on_the_volume_and_the_segmented_volume(ribs_ngp, tmp_path):
    out, sc = ribs_ngp
    obj = _import(out / "ribs.ingp")
    bpy.context.scene.divas.render_scale = 0.25
    bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(
        segmenter="oracle", gt_labels=str(out / "labels_ngp.npy"), device="cpu"
    ) == {"FINISHED"}
    live = session_registry.get(obj)
    s = live.session
    assert s.kind == "nerf" and len(s.anchors) >= 1
    cam = s.anchors[0].camera
    clicks = [c["xyz"] for c in sc.metadata["clicks"]]
    uv, z = cam.project(np.array(clicks))
    ok = (
        (z > 0)
        & (uv[:, 0] >= 0)
        & (uv[:, 0] < cam.width)
        & (uv[:, 1] >= 0)
        & (uv[:, 1] < cam.height)
    )
    if not ok.any():
        pytest.skip("no click point in the first anchor")
    x, y = (float(v) for v in uv[np.argmax(ok)])
    assert bpy.ops.divas.session_click(anchor=0, xy=f"{x!r} {y!r}") == {"FINISHED"}
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    assert s.selection.sum() > 20
    # the segmented part as a new, selectable Volume
    assert bpy.ops.divas.segmented_volume() == {"FINISHED"}
    seg = bpy.context.active_object
    assert seg.type == "VOLUME" and not seg.hide_select and seg is not obj
    assert seg[nerf_volume.VOLUME_PROP] == "segment"
    np.testing.assert_allclose(np.array(seg.matrix_world), np.array(obj.matrix_world))
    if HAS_VDB:
        masked = read_vdb(seg.data.filepath)
        n_sel = int((s.selection & (s.scene.density > 0)).sum())
        assert int((masked.density > 0).sum()) == n_sel
    # export: the masked snapshot and the .vdb beside it
    bpy.context.view_layer.objects.active = obj
    target = tmp_path / "ribs_sel.ingp"
    assert bpy.ops.divas.export_selection(filepath=str(target)) == {"FINISHED"}
    assert (tmp_path / "ribs_sel.vdb").is_file()
    doc, _ = read_ngp_document(target)
    m = load_scene(target)
    assert 0 < int((m.density > 0).sum()) <= int((s.scene.density > 0).sum())
    assert doc["snapshot"]["nerf"]["aabb_scale"] == 1


def test_segmented_volume_needs_a_selection(ribs_ngp):
    out, _ = ribs_ngp
    obj = _import(out / "ribs.ingp")
    assert not bpy.ops.divas.segmented_volume.poll()
    bridge.write_attribute(obj.data, SELECTED, np.zeros(len(obj.data.points), bool))
    with pytest.raises(RuntimeError, match="nothing is selected"):
        bpy.ops.divas.segmented_volume()

"""A Blender without an OpenVDB Python module (the ``bpy`` 4.2 wheel has none): Import ›
NeRF still makes the Volume (the engine's NumPy writer, Blender's own reader), and so
does Segmented Volume; where a Volume cannot be made the grid is shown as points with
one warning line; a ``.vdb`` input is one error line, never a traceback."""

from __future__ import annotations

import numpy as np
import pytest

from blender_addon import bridge, compat, nerf_volume
from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.io import openvdb_grid
from divas_engine.io.instant_ngp import write_ngp_document
from divas_engine.point_attributes import SELECTED
from divas_engine.synthetic.ngp_snapshot import snapshot_of_grid

bpy = pytest.importorskip("bpy")


@pytest.fixture(autouse=True)
def volumes_in_tmp(tmp_path_factory, monkeypatch):
    folder = tmp_path_factory.mktemp("volumes")
    monkeypatch.setattr(nerf_volume, "volume_dir", lambda: folder)


@pytest.fixture
def no_openvdb(monkeypatch):
    """The engine's finder (which the add-on uses too) finds no module."""
    monkeypatch.setattr(openvdb_grid, "openvdb_module", lambda: None)


@pytest.fixture(scope="module")
def ribs_ingp(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_novdb")
    sc = generate_scene("ribs", out, size=4_000, seed=0, grid_resolution=24)
    path = out / "ribs.ingp"
    write_ngp_document(path, snapshot_of_grid(sc.grid, sc.cameras[:2], network=False), True)
    return path


def test_the_add_on_and_the_engine_share_one_finder():
    assert compat.openvdb() is openvdb_grid.openvdb_module()


def _check_volume_file(vol, grid):
    """Blender read the ``density`` grid with the lattice's transform (index → object:
    voxel size and the first voxel's centre)."""
    vol.data.grids.load()
    names = {g.name for g in vol.data.grids}
    assert "density" in names
    m = np.array(vol.data.grids["density"].matrix_object)
    vox = grid.voxel_size
    np.testing.assert_allclose(np.diag(m)[:3], vox, rtol=1e-6)
    np.testing.assert_allclose(m[:3, 3], grid.aabb[0] + 0.5 * vox, atol=1e-6)


def test_import_makes_the_volume_without_an_openvdb_module(no_openvdb, ribs_ingp, capfd):
    assert bpy.ops.divas.import_density_grid(filepath=str(ribs_ingp)) == {"FINISHED"}
    obj = bpy.context.active_object
    vol = nerf_volume.display_volume_of(obj)
    assert vol is not None and obj.display_type == "BOUNDS"
    _check_volume_file(vol, load_scene(ribs_ingp))
    out = capfd.readouterr()
    assert "Traceback" not in out.err and "shown as points" not in out.out + out.err


def test_the_numpy_written_volume_holds_the_grid(ribs_ingp, tmp_path, monkeypatch):
    """Written without a module, read back with one (skipped where none exists)."""
    finder = openvdb_grid.openvdb_module
    if finder() is None:
        pytest.skip("no OpenVDB module to read the file back with")
    grid = load_scene(ribs_ingp)
    monkeypatch.setattr(openvdb_grid, "openvdb_module", lambda: None)
    path = nerf_volume.write_grid_vdb(grid, None, "check")
    monkeypatch.setattr(openvdb_grid, "openvdb_module", finder)
    back = openvdb_grid.read_vdb(path)
    np.testing.assert_allclose(back.aabb, grid.aabb, atol=1e-9)
    assert np.array_equal(back.density, grid.density.astype(np.float32))


def test_segmented_volume_without_an_openvdb_module(no_openvdb, ribs_ingp):
    assert bpy.ops.divas.import_density_grid(filepath=str(ribs_ingp)) == {"FINISHED"}
    obj = bpy.context.active_object
    sel = np.zeros(len(obj.data.points), bool)
    sel[::3] = True
    bridge.write_attribute(obj.data, SELECTED, sel)
    assert bpy.ops.divas.segmented_volume() == {"FINISHED"}
    seg = bpy.context.active_object
    assert seg.type == "VOLUME" and seg[nerf_volume.VOLUME_PROP] == "segment"
    assert seg["divas_voxels"] == int(sel.sum())
    _check_volume_file(seg, load_scene(ribs_ingp))


def test_import_falls_back_to_points_with_one_warning(ribs_ingp, monkeypatch, capfd):
    def fail(context, obj, grid):
        raise DivasInputError("x.vdb", "Blender read no grid from this volume file")

    monkeypatch.setattr(nerf_volume, "add_display_volume", fail)
    assert bpy.ops.divas.import_density_grid(filepath=str(ribs_ingp)) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.type == "POINTCLOUD" and len(obj.data.points) > 0
    assert nerf_volume.display_volume_of(obj) is None
    assert len(obj.modifiers) == 1 and obj.display_type != "BOUNDS" and not obj.hide_render
    out = capfd.readouterr()
    text = out.out + out.err
    assert "Traceback" not in text
    lines = [ln for ln in text.splitlines() if "shown as points" in ln]
    assert len(lines) == 1 and "Blender read no grid" in lines[0]


def test_a_vdb_input_is_one_error_line(no_openvdb, tmp_path, capfd):
    path = tmp_path / "smoke.vdb"
    path.write_bytes(b"\x20BDV" + bytes(60))
    with pytest.raises(RuntimeError) as err:
        bpy.ops.divas.import_density_grid(filepath=str(path))
    msg = str(err.value).strip()
    assert "smoke.vdb" in msg and "OpenVDB" in msg and "\n" not in msg
    assert "Traceback" not in capfd.readouterr().err


def test_blender_reads_the_numpy_written_tree(no_openvdb, tmp_path):
    """Blender's own reader finds the leaves where the occupied voxels are: the evaluated
    Volume's bounds are the 8³ leaves around them (their voxels' centres, or faces from
    Blender 5.0: half a voxel either way)."""
    from divas_engine.io.openvdb_grid import write_vdb
    from divas_engine.scene import DensityGrid

    d = np.zeros((40, 40, 40), np.float32)  # [z, y, x]
    d[25:31, 9:13, 17:23] = 1.5
    grid = DensityGrid(d, np.array([[0.0, 0, 0], [4.0, 4.0, 4.0]]))
    vol = bpy.data.volumes.new("check")
    vol.filepath = str(write_vdb(tmp_path / "tree.vdb", grid))
    vol.grids.load()
    obj = bpy.data.objects.new("check", vol)
    bpy.context.scene.collection.objects.link(obj)
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    bb = np.array([list(v) for v in ev.bound_box])
    leaf_lo = np.array([16, 8, 24])  # x, y, z voxels of the leaves' first voxels
    leaf_hi = np.array([23, 15, 31])
    np.testing.assert_allclose(bb.min(0), (leaf_lo + 0.5) * 0.1, atol=0.05 + 1e-6)
    np.testing.assert_allclose(bb.max(0), (leaf_hi + 0.5) * 0.1, atol=0.05 + 1e-6)

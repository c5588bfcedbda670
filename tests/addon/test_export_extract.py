"""Export and extract from a ``divas_selected`` attribute.

Export through the operator must give the file ``divas_engine.export.export_selection``
writes for the same selection (byte-identical for splat formats, same arrays for grids);
extract must give an object with exactly the selected points and their attributes.
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge, display, source
from divas_engine import load_scene
from divas_engine.export import export_selection

SELECTED = "divas_selected"


def _import(op, path):
    assert op(filepath=str(path)) == {"FINISHED"}
    return bpy.context.active_object


def _select(obj, seed=0, frac=0.3) -> np.ndarray:
    n = len(obj.data.points)
    sel = np.random.default_rng(seed).random(n) < frac
    bridge.write_attribute(obj.data, SELECTED, sel)
    return sel


def _engine_mask(scene, obj, sel):
    """The engine selection the points' selection means (by file row / voxel index)."""
    idx = bridge.read_attribute(obj.data, "divas_index")[sel]
    if hasattr(scene, "density"):
        mask = np.zeros(scene.density.size, bool)
        mask[idx] = True
        return mask.reshape(scene.density.shape)
    return np.isin(scene.source.kept_rows, idx)


@pytest.mark.parametrize("which", ["ribs", "lod3", "guitar", "biker_spz"])
def test_export_matches_engine(ribs, real_data, tmp_path, which):
    path = {
        "ribs": ribs / "scene.ply",
        "lod3": real_data / "gaussiansplats3d-lod" / "lod3_tile_0.ply",
        "guitar": real_data / "playcanvas-splats" / "guitar.compressed.ply",
        "biker_spz": real_data / "playcanvas-splats" / "biker.spz",
    }[which]
    obj = _import(bpy.ops.divas.import_splats, path)
    sel = _select(obj)
    suffix = ".spz" if which == "biker_spz" else ".ply"
    out = tmp_path / f"ours{suffix}"
    assert bpy.ops.divas.export_selection(filepath=str(out), write_labels=True) == {"FINISHED"}
    scene = load_scene(path)
    ref = tmp_path / f"engine{suffix}"
    res = export_selection(
        scene, _engine_mask(scene, obj, sel), ref, labels_path=tmp_path / "ref_labels.npy"
    )
    assert res.count == sel.sum()
    assert out.read_bytes() == ref.read_bytes()
    np.testing.assert_array_equal(
        np.load(tmp_path / "ours_labels.npy"), np.load(tmp_path / "ref_labels.npy")
    )


def test_export_density_grid(ribs, tmp_path):
    obj = _import(bpy.ops.divas.import_density_grid, ribs / "grid.npz")
    sel = _select(obj, seed=4, frac=0.5)
    out = tmp_path / "sel.npz"
    assert bpy.ops.divas.export_selection(filepath=str(out)) == {"FINISHED"}
    grid = load_scene(ribs / "grid.npz")
    ref = tmp_path / "ref.npz"
    export_selection(grid, _engine_mask(grid, obj, sel), ref)
    with np.load(out) as a, np.load(ref) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_export_adds_the_source_suffix(ribs, tmp_path):
    obj = _import(bpy.ops.divas.import_splats, ribs / "scene.ply")
    _select(obj)
    assert bpy.ops.divas.export_selection(filepath=str(tmp_path / "noext")) == {"FINISHED"}
    assert (tmp_path / "noext.ply").is_file()


def test_export_needs_selection(ribs, tmp_path):
    obj = _import(bpy.ops.divas.import_splats, ribs / "scene.ply")
    assert not bpy.ops.divas.export_selection.poll()  # no divas_selected attribute yet
    bridge.write_attribute(obj.data, SELECTED, np.zeros(len(obj.data.points), bool))
    with pytest.raises(RuntimeError, match="nothing to export"):
        bpy.ops.divas.export_selection(filepath=str(tmp_path / "empty.ply"))
    assert not (tmp_path / "empty.ply").exists()


def test_export_reports_missing_source(ribs, tmp_path):
    import shutil

    copy = tmp_path / "copy.ply"
    shutil.copy(ribs / "scene.ply", copy)
    obj = _import(bpy.ops.divas.import_splats, copy)
    _select(obj)
    copy.unlink()
    with pytest.raises(RuntimeError, match="copy.ply"):
        bpy.ops.divas.export_selection(filepath=str(tmp_path / "out.ply"))


@pytest.mark.parametrize("kind", ["splats", "grid"])
def test_extract_selection(ribs, kind):
    if kind == "splats":
        obj = _import(bpy.ops.divas.import_splats, ribs / "scene.ply")
    else:  # the points display (a Volume display has no modifier to carry over)
        grid_points = lambda filepath: bpy.ops.divas.import_density_grid(  # noqa: E731
            filepath=filepath, display_as="POINTS"
        )
        obj = _import(grid_points, ribs / "grid.npz")
    obj.location = (1.0, 2.0, 3.0)
    sel = _select(obj, seed=2)
    before = bridge.read_attributes(obj.data)
    assert bpy.ops.divas.extract_selection() == {"FINISHED"}
    new = bpy.context.active_object
    assert new != obj and new.type == "POINTCLOUD"
    assert len(new.data.points) == sel.sum()
    after = bridge.read_attributes(new.data)
    assert set(after) == set(before) - {SELECTED}
    for name, (data_type, values) in after.items():
        assert data_type == before[name][0], name
        np.testing.assert_array_equal(values, before[name][1][sel], err_msg=name)
    assert source.source_of(new) == source.source_of(obj)
    assert tuple(new.location) == (1.0, 2.0, 3.0)
    assert new.modifiers[display.MODIFIER].node_group == obj.modifiers[display.MODIFIER].node_group
    # the source object is untouched
    np.testing.assert_array_equal(bridge.read_attribute(obj.data, SELECTED), sel)
    assert "UNDO" in bpy.types.DIVAS_OT_extract_selection.bl_options


def test_export_from_extracted_object(ribs, tmp_path):
    """Extracted points keep file rows, so exporting all of them writes the same subset."""
    obj = _import(bpy.ops.divas.import_splats, ribs / "scene.ply")
    sel = _select(obj, seed=5)
    bpy.ops.divas.export_selection(filepath=str(tmp_path / "a.ply"))
    bpy.ops.divas.extract_selection()
    new = bpy.context.active_object
    bridge.write_attribute(new.data, SELECTED, np.ones(int(sel.sum()), bool))
    bpy.ops.divas.export_selection(filepath=str(tmp_path / "b.ply"))
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_extract_empty_selection(ribs):
    obj = _import(bpy.ops.divas.import_splats, ribs / "scene.ply")
    bridge.write_attribute(obj.data, SELECTED, np.zeros(len(obj.data.points), bool))
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="nothing to extract"):
        bpy.ops.divas.extract_selection()
    assert len(bpy.data.objects) == n


def test_bridge_round_trip_types():
    obj = bridge.new_point_cloud_object("t", np.zeros((7, 3)), bpy.context.scene.collection)
    geom = obj.data
    rng = np.random.default_rng(0)
    arrays = {
        "f": rng.random(7).astype(np.float32),
        "i": rng.integers(-9, 9, 7).astype(np.int32),
        "b": rng.random(7) < 0.5,
        "v": rng.random((7, 3)).astype(np.float32),
        "c": rng.random((7, 4)).astype(np.float32),
        "f2": rng.random((7, 2)).astype(np.float32),
    }
    bridge.write_attributes(geom, arrays)
    types = {
        "f": "FLOAT",
        "i": "INT",
        "b": "BOOLEAN",
        "v": "FLOAT_VECTOR",
        "c": "FLOAT_COLOR",
        "f2": "FLOAT2",
    }
    for k, v in arrays.items():
        assert geom.attributes[k].data_type == types[k]
        np.testing.assert_array_equal(bridge.read_attribute(geom, k), v)
    bridge.write_attribute(geom, "f", np.arange(7, dtype=np.int32))  # retyped in place
    assert geom.attributes["f"].data_type == "INT"
    with pytest.raises(ValueError, match="7 points"):
        bridge.write_attribute(geom, "x", np.zeros(6, np.float32))
    with pytest.raises(KeyError):
        bridge.read_attribute(geom, "nope")
    assert ".select_vert" not in geom.attributes and len(bpy.data.meshes) == 1  # the cube only


@pytest.mark.parametrize("transform", ["OBJECT", "WORLD"])
def test_export_applying_the_object_transform(real_data, tmp_path, transform):
    """Apply Transform: OBJECT bakes the transform *since import* (the file keeps its own
    axes), WORLD the whole object matrix; the file equals the engine's transformed export
    of the same selection and matrix."""
    from divas_engine.transform_export import export_transformed_selection

    path = real_data / "gaussiansplats3d-lod" / "lod3_tile_0.ply"
    obj = _import(bpy.ops.divas.import_splats, path)
    frame = np.array(obj.matrix_world)
    obj.rotation_euler = (0.5, -0.3, 1.2)
    obj.location = (1.0, 2.0, -0.5)
    obj.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    sel = _select(obj, seed=3, frac=0.6)
    out = tmp_path / "moved.ply"
    assert bpy.ops.divas.export_selection(filepath=str(out), apply_transform=transform) == {
        "FINISHED"
    }
    world = np.array(obj.matrix_world, np.float64)
    m = world if transform == "WORLD" else np.linalg.inv(frame) @ world
    scene = load_scene(path)
    ref = tmp_path / "ref.ply"
    export_transformed_selection(scene, _engine_mask(scene, obj, sel), ref, m)
    assert out.read_bytes() == ref.read_bytes()
    got = load_scene(out)
    np.testing.assert_allclose(
        got.means, scene.means[_engine_mask(scene, obj, sel)] @ m[:3, :3].T + m[:3, 3], atol=1e-4
    )
    if transform == "OBJECT":  # untouched object → the file's own frame, rows unchanged
        obj.matrix_world = __import__("mathutils").Matrix(frame.tolist())
        bpy.context.view_layer.update()
        same = tmp_path / "same.ply"
        bpy.ops.divas.export_selection(filepath=str(same), apply_transform="OBJECT")
        np.testing.assert_allclose(
            load_scene(same).means, scene.means[_engine_mask(scene, obj, sel)], atol=1e-5
        )


def test_export_applying_a_transform_to_spz_is_refused(real_data, tmp_path):
    obj = _import(bpy.ops.divas.import_splats, real_data / "playcanvas-splats" / "biker.spz")
    _select(obj)
    with pytest.raises(RuntimeError, match="spz"):
        bpy.ops.divas.export_selection(filepath=str(tmp_path / "x.spz"), apply_transform="OBJECT")
    assert not (tmp_path / "x.spz").exists()

"""Import operators for splat scenes and density grids: every file property and engine
attribute round-trips exactly; bad files are reported by name.

Real scenes: ``gaussiansplats3d-lod/lod3_tile_0.ply`` (mkkellogg/GaussianSplats3D, MIT) and
``playcanvas-splats/guitar.compressed.ply`` / ``biker.spz`` (playcanvas/engine, MIT), see
``tests/data/README.md``.
"""

from __future__ import annotations

import time

import bpy
import numpy as np
import plyfile
import pytest

from blender_addon import bridge, display, source
from divas_engine import load_scene
from divas_engine.geometry import quat_to_rotmat
from divas_engine.io.ply import write_surfel_ply
from divas_engine.point_attributes import (
    decoded_columns,
    display_radius,
    grid_point_table,
    surfel_point_table,
)
from divas_engine.scene import SurfelScene


def _import(path) -> bpy.types.Object:
    assert bpy.ops.divas.import_splats(filepath=str(path)) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.type == "POINTCLOUD"
    return obj


def _check_engine_columns(obj, scene):
    geom = obj.data
    assert len(geom.points) == len(scene)
    np.testing.assert_array_equal(bridge.read_attribute(geom, "position"), scene.means)
    np.testing.assert_array_equal(
        bridge.read_attribute(geom, "divas_index"), scene.source.kept_rows
    )
    np.testing.assert_array_equal(bridge.read_attribute(geom, "divas_opacity"), scene.opacities)
    color = bridge.read_attribute(geom, "divas_color")
    np.testing.assert_array_equal(color[:, :3], scene.base_colors().astype(np.float32))
    np.testing.assert_array_equal(color[:, 3], scene.opacities)
    np.testing.assert_array_equal(
        bridge.read_attribute(geom, "divas_radius"), display_radius(scene.scales)
    )
    assert geom.attributes["divas_color"].data_type == "FLOAT_COLOR"
    assert geom.attributes["divas_index"].data_type == "INT"


def _check_ply_rows(obj, path, kept_rows):
    """Every vertex property equals the file's raw value, row for row (plyfile reads it)."""
    rows = plyfile.PlyData.read(str(path))["vertex"].data[kept_rows]
    geom = obj.data
    for name in rows.dtype.names:
        attr = geom.attributes[name]
        assert attr.data_type == "FLOAT" and attr.domain == "POINT"
        np.testing.assert_array_equal(bridge.read_attribute(geom, name), rows[name], err_msg=name)


def test_import_synthetic_2dgs(ribs):
    path = ribs / "scene.ply"
    obj = _import(path)
    scene = load_scene(path)
    _check_ply_rows(obj, path, scene.source.kept_rows)
    _check_engine_columns(obj, scene)
    assert obj.name == "scene"
    assert source.source_of(obj) == source.SourceRef(path.resolve(), "ply", "surfels")
    mod = obj.modifiers[display.MODIFIER]
    assert mod.type == "NODES" and mod.node_group.name == display.DISPLAY_GROUP
    assert obj.data.materials[0].name == display.MATERIAL
    # the display modifier turns divas_radius into the evaluated point radius
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg).data
    radius = np.empty(len(ev.points), np.float32)
    ev.attributes["radius"].data.foreach_get("value", radius)
    np.testing.assert_allclose(radius, display_radius(scene.scales), rtol=1e-6)


def test_import_without_display(ribs):
    assert bpy.ops.divas.import_splats(filepath=str(ribs / "scene.ply"), display=False) == {
        "FINISHED"
    }
    assert len(bpy.context.active_object.modifiers) == 0


def test_import_real_3dgs_ply(real_data):
    path = real_data / "gaussiansplats3d-lod" / "lod3_tile_0.ply"
    obj = _import(path)
    scene = load_scene(path)
    assert len(obj.data.points) == 1971
    _check_ply_rows(obj, path, scene.source.kept_rows)
    _check_engine_columns(obj, scene)
    assert obj.data.attributes.get("scale_2") is not None  # 3DGS: all three raw scales kept
    assert len([n for n in bridge.attribute_names(obj.data) if n.startswith("f_rest_")]) == 45


def test_import_real_compressed_ply(real_data):
    path = real_data / "playcanvas-splats" / "guitar.compressed.ply"
    obj = _import(path)
    scene = load_scene(path)
    geom = obj.data
    assert len(geom.points) == len(scene) == 90_854
    # raw packed words, bit-for-bit (uint32 stored bit-cast in INT attributes)
    rows = plyfile.PlyData.read(str(path))["vertex"].data[scene.source.kept_rows]
    for name in ("packed_position", "packed_rotation", "packed_scale", "packed_color"):
        assert geom.attributes[name].data_type == "INT"
        np.testing.assert_array_equal(bridge.read_attribute(geom, name).view(np.uint32), rows[name])
    # and the decoded values under the standard names
    for name, values in decoded_columns(scene).items():
        np.testing.assert_array_equal(bridge.read_attribute(geom, name), values, err_msg=name)
    _check_engine_columns(obj, scene)
    assert source.source_of(obj).format == "compressed_ply"


def test_import_real_spz(real_data):
    path = real_data / "playcanvas-splats" / "biker.spz"
    obj = _import(path)
    scene = load_scene(path)
    for name, values in decoded_columns(scene).items():
        np.testing.assert_array_equal(bridge.read_attribute(obj.data, name), values, err_msg=name)
    _check_engine_columns(obj, scene)
    # decoded columns reproduce the engine's surfels (stored space → activated)
    np.testing.assert_allclose(
        np.exp(bridge.read_attribute(obj.data, "scale_1")), scene.scales[:, 1], rtol=1e-5
    )
    q = np.stack([bridge.read_attribute(obj.data, f"rot_{i}") for i in range(4)], 1)
    np.testing.assert_allclose(quat_to_rotmat(q), scene.rotations(), atol=1e-6)


def test_reserved_property_names_are_prefixed(tmp_path):
    rng = np.random.default_rng(1)
    n = 300
    fields = [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("f_dc_0", "<f4"),
        ("f_dc_1", "<f4"),
        ("f_dc_2", "<f4"),
        ("opacity", "<f4"),
        ("scale_0", "<f4"),
        ("scale_1", "<f4"),
        ("rot_0", "<f4"),
        ("rot_1", "<f4"),
        ("rot_2", "<f4"),
        ("rot_3", "<f4"),
        ("radius", "<f4"),
        ("label", "<u4"),
        ("flag", "u1"),
        ("weight", "<f8"),
    ]
    rows = np.zeros(n, fields)
    for f, _ in fields:
        rows[f] = rng.uniform(-1, 1, n) if f not in ("label", "flag") else rng.integers(0, 200, n)
    rows["label"][0] = 4_000_000_000  # above int32: stored bit-cast
    rows["rot_0"] = 1.0
    path = tmp_path / "extra.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")]).write(str(path))
    obj = _import(path)
    geom = obj.data
    np.testing.assert_array_equal(bridge.read_attribute(geom, "ply_radius"), rows["radius"])
    np.testing.assert_array_equal(
        bridge.read_attribute(geom, "label").view(np.uint32), rows["label"]
    )
    np.testing.assert_array_equal(bridge.read_attribute(geom, "flag"), rows["flag"])
    np.testing.assert_array_equal(
        bridge.read_attribute(geom, "weight"), rows["weight"].astype(np.float32)
    )


def test_import_density_grid(ribs):
    path = ribs / "grid.npz"
    assert bpy.ops.divas.import_density_grid(filepath=str(path), min_opacity=0.05) == {"FINISHED"}
    obj = bpy.context.active_object
    grid = load_scene(path)
    table = grid_point_table(grid, 0.05)
    geom = obj.data
    assert len(geom.points) == len(table) > 0
    np.testing.assert_array_equal(bridge.read_attribute(geom, "position"), table.positions)
    for name, values in table.columns.items():
        np.testing.assert_array_equal(bridge.read_attribute(geom, name), values, err_msg=name)
    # points sit at cell centres of the voxels they index
    iz, iy, ix = np.unravel_index(table.columns["divas_index"], grid.density.shape)
    centre = grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * grid.voxel_size
    np.testing.assert_allclose(table.positions, centre, atol=1e-5)
    np.testing.assert_array_equal(table.columns["divas_density"], grid.density[iz, iy, ix])
    assert source.source_of(obj) == source.SourceRef(path.resolve(), "npz", "grid")
    assert list(obj["divas_grid_shape"]) == list(grid.density.shape)


@pytest.mark.parametrize(
    "case", ["missing", "garbage", "truncated", "grid_as_splats", "splats_as_grid"]
)
def test_bad_input_is_reported_by_name(ribs, tmp_path, case):
    op = bpy.ops.divas.import_splats
    if case == "missing":
        path = tmp_path / "missing.ply"
    elif case == "garbage":
        path = tmp_path / "garbage.ply"
        path.write_bytes(b"this is not a ply file")
    elif case == "truncated":
        path = tmp_path / "truncated.ply"
        path.write_bytes((ribs / "scene.ply").read_bytes()[:5000])
    elif case == "grid_as_splats":
        path = ribs / "grid.npz"
    else:
        path, op = ribs / "scene.ply", bpy.ops.divas.import_density_grid
    n_objects = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match=path.name):
        op(filepath=str(path))
    assert len(bpy.data.objects) == n_objects  # nothing half-built left behind


def test_reports_return_cancelled(tmp_path):
    """The operator's own return value on failure (reports captured without bpy.ops)."""
    from blender_addon.operators.import_splats import DIVAS_OT_import_splats

    class Fake:
        filepath, display = str(tmp_path / "nope.splat"), True
        reports = []

        def report(self, level, msg):
            self.reports.append((level, msg))

    fake = Fake()
    assert DIVAS_OT_import_splats.execute(fake, bpy.context) == {"CANCELLED"}
    assert fake.reports[0][0] == {"ERROR"} and "nope.splat" in fake.reports[0][1]


def test_import_one_million_splats_timing(tmp_path, capsys):
    """1M SH-degree-1 2DGS surfels (33 PLY properties): the import time is printed."""
    n = 1_000_000
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scene = SurfelScene(
        rng.normal(size=(n, 3)).astype(np.float32),
        q,
        rng.uniform(0.001, 0.02, (n, 2)).astype(np.float32),
        rng.uniform(0.05, 0.95, n).astype(np.float32),
        rng.normal(size=(n, 4, 3)).astype(np.float32) * 0.3,
        1,
    )
    path = tmp_path / "million.ply"
    write_surfel_ply(path, scene)
    t0 = time.perf_counter()
    obj = _import(path)
    dt = time.perf_counter() - t0
    assert len(obj.data.points) == n
    with capsys.disabled():
        print(
            f"\n[import] 1,000,000 splats, {len(bridge.attribute_names(obj.data))} attributes: "
            f"{dt:.2f} s"
        )
    table_cols = surfel_point_table(load_scene(path)).columns
    np.testing.assert_array_equal(
        bridge.read_attribute(obj.data, "f_rest_8"), table_cols["f_rest_8"]
    )


def test_import_from_edit_mode(ribs):
    cube = bpy.data.objects["Cube"]
    bpy.context.view_layer.objects.active = cube
    bpy.ops.object.mode_set(mode="EDIT")
    assert bpy.context.mode == "EDIT_MESH"
    obj = _import(ribs / "scene.ply")
    assert bpy.context.mode == "OBJECT" and len(obj.data.points) == 20_000

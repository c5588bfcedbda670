"""Per-point attribute tables (:mod:`divas_engine.point_attributes`) without Blender."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from divas_engine import load_scene
from divas_engine.io.ply import write_surfel_ply
from divas_engine.point_attributes import (
    ENGINE_COLUMNS,
    dequantize_sh,
    display_radius,
    grid_point_table,
    linear_to_srgb,
    point_values,
    quantize_sh,
    scene_selection,
    srgb_to_linear,
    surfel_point_table,
)
from divas_engine.scene import SH_C0, DensityGrid, SourceInfo, SurfelScene


def _scene(n=50, seed=0) -> SurfelScene:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return SurfelScene(
        rng.normal(size=(n, 3)).astype(np.float32),
        q,
        rng.uniform(0.01, 0.1, (n, 2)).astype(np.float32),
        rng.uniform(0.1, 0.9, n).astype(np.float32),
        rng.normal(size=(n, 4, 3)).astype(np.float32),
        1,
    )


def test_ply_table_holds_each_value_once_and_skips_dropped(tmp_path):
    clean, path = tmp_path / "clean.ply", tmp_path / "s.ply"
    write_surfel_ply(clean, _scene())
    ply = plyfile.PlyData.read(str(clean), mmap=False)
    ply["vertex"].data["x"][[3, 7]] = np.nan  # dropped on load
    ply.write(str(path))
    scene = load_scene(path)
    table = surfel_point_table(scene)
    kept = np.setdiff1d(np.arange(50), [3, 7])
    np.testing.assert_array_equal(table.columns["divas_index"], kept)
    np.testing.assert_array_equal(table.positions, scene.means)
    # standard trainer properties are decoded once (engine columns), never kept raw
    assert list(table.columns) == [*ENGINE_COLUMNS, "divas_sh_1", "divas_sh_2", "divas_sh_3"]
    assert table.kinds == {"divas_color": "color", "divas_rotation": "quaternion"}
    np.testing.assert_array_equal(table.columns["divas_rotation"], scene.quats)
    np.testing.assert_array_equal(table.columns["divas_scale"][:, :2], scene.scales)
    assert not table.columns["divas_scale"][:, 2].any()  # 2DGS: no normal σ
    np.testing.assert_array_equal(table.columns["divas_color"][:, 3], scene.opacities)
    assert all(v.flags.c_contiguous for v in table.columns.values())
    assert table.meta["sh_degree"] == 1 and table.meta["sh_range"][1:] == [0.0, 0.0]


def test_colour_is_the_sh_dc_colour_decoded_from_srgb():
    s = _scene()
    col = surfel_point_table(s).columns["divas_color"][:, :3].astype(np.float64)
    shown = 0.5 + SH_C0 * s.sh[:, 0].astype(np.float64)
    # the IEC 61966-2-1 formula written out, extended sign-symmetrically
    a = np.abs(shown)
    ref = np.sign(shown) * np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(col, ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(linear_to_srgb(col), shown, rtol=1e-5, atol=1e-6)
    # a dark capture colour stays dark: 0.10 on screen is 0.010 in linear light
    np.testing.assert_allclose(srgb_to_linear(0.1), 0.0100228, rtol=1e-5)


def test_sh_codes_keep_coefficients_to_half_a_step():
    rng = np.random.default_rng(2)
    n = 4000
    rest = rng.normal(scale=0.2, size=(n, 15, 3))
    rest[0, 5, 1] = 9.0  # an outlier beyond the band's range clips instead of widening it
    codes, ranges = quantize_sh(rest, 3)
    assert len(codes) == 15 and all(c.dtype == np.int32 for c in codes)
    assert all(c.min() >= 0 and c.max() < 1 << 24 for c in codes)  # exact in a float32
    zero, zr = quantize_sh(np.zeros((3, 3, 3)), 1)
    assert zr.tolist() == [0.0, 0.0, 0.0] and not dequantize_sh(zero, zr).any()
    back = dequantize_sh(codes, ranges)
    band = np.array([1] * 3 + [2] * 5 + [3] * 7)
    step = ranges[band - 1] / 127.0
    inside = np.abs(rest) <= ranges[band - 1][None, :, None]
    err = np.abs(back - rest)
    half = np.broadcast_to(step[None, :, None] / 2, err.shape)
    assert np.all(err[inside] <= half[inside] + 1e-12)
    assert back[0, 5, 1] == pytest.approx(ranges[1])
    assert ranges[1] < 1.0  # the P99.9 range, not the outlier


def test_display_radius_clips_outliers():
    scales = np.full((1000, 2), 0.01, np.float32)
    scales[0] = 50.0
    r = display_radius(scales)
    assert r[1] == pytest.approx(0.02) and r[0] < 1.0


def test_scene_selection_maps_file_rows():
    s = _scene(10)
    s.source = SourceInfo("x.ply", "ply", 12, np.array([0, 1, 2, 4, 5, 6, 8, 9, 10, 11]))
    mask = scene_selection(s, np.array([11, 4, 0]), np.array([True, True, False]))
    np.testing.assert_array_equal(np.flatnonzero(mask), [3, 9])
    with pytest.raises(ValueError, match="not a primitive"):
        scene_selection(s, np.array([3]), np.array([True]))
    with pytest.raises(ValueError, match="not a primitive"):
        scene_selection(s, np.array([12]), np.array([True]))
    with pytest.raises(ValueError, match="shape"):
        scene_selection(s, np.array([1, 2]), np.array([True]))


def test_grid_table_and_selection():
    dens = np.zeros((4, 5, 6), np.float32)
    dens[1, 2, 3] = 100.0
    dens[2, 0, 0] = 1e-6  # below the opacity threshold
    grid = DensityGrid(dens, np.array([[0, 0, 0], [6, 5, 4]], float))
    t = grid_point_table(grid, 0.01)
    assert len(t) == 1
    np.testing.assert_allclose(t.positions[0], [3.5, 2.5, 1.5])
    assert t.columns["divas_index"][0] == np.ravel_multi_index((1, 2, 3), dens.shape)
    mask = scene_selection(grid, t.columns["divas_index"], np.array([True]))
    assert mask.shape == dens.shape and mask[1, 2, 3] and mask.sum() == 1
    with pytest.raises(ValueError, match="no voxel"):
        grid_point_table(DensityGrid(dens * 1e-9, grid.aabb), 0.01)


def test_point_values_invert_scene_selection_on_file_rows():
    s = _scene(10)
    kept = np.array([0, 1, 2, 4, 5, 6, 8, 9, 10, 11])
    s.source = SourceInfo("x.ply", "ply", 12, kept)
    labels = np.arange(10, 20)  # per primitive; primitive k is file row kept[k]
    index = np.array([11, 4, 0, 4])  # a host's points, any order, repeats allowed
    np.testing.assert_array_equal(point_values(s, index, labels), [19, 13, 10, 13])
    # inverse of scene_selection: per-point selection → primitives → per-point again
    rng = np.random.default_rng(1)
    index = rng.permutation(kept)
    selected = rng.random(len(index)) < 0.5
    mask = scene_selection(s, index, selected)
    np.testing.assert_array_equal(point_values(s, index, mask), selected)
    assert point_values(s, np.array([], np.int64), labels).shape == (0,)
    for bad in ([3], [12], [-1]):
        with pytest.raises(ValueError, match="not a primitive"):
            point_values(s, np.array(bad), labels)


def test_point_values_without_source_and_on_grids():
    s = _scene(5)
    s.source = None
    np.testing.assert_array_equal(point_values(s, np.array([4, 0]), np.arange(5) * 2), [8, 0])
    dens = np.ones((2, 3, 4), np.float32)
    grid = DensityGrid(dens, np.array([[0, 0, 0], [4, 3, 2]], float))
    values = np.arange(24).reshape(2, 3, 4)
    flat = np.array([np.ravel_multi_index((1, 2, 3), dens.shape), 0])
    np.testing.assert_array_equal(point_values(grid, flat, values), [values[1, 2, 3], 0])
    keep = np.zeros(dens.shape, bool)
    keep[1, 0, 2] = True
    index = np.arange(24)
    np.testing.assert_array_equal(
        scene_selection(grid, index, point_values(grid, index, keep)), keep
    )
    with pytest.raises(ValueError, match="outside the density grid"):
        point_values(grid, np.array([24]), values)

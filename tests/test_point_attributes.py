"""Per-point attribute tables (:mod:`divas_engine.point_attributes`) without Blender."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from divas_engine import load_scene
from divas_engine.io.ply import write_surfel_ply
from divas_engine.point_attributes import (
    ENGINE_COLUMNS,
    decoded_columns,
    display_radius,
    grid_point_table,
    point_values,
    scene_selection,
    surfel_point_table,
)
from divas_engine.scene import DensityGrid, SourceInfo, SurfelScene


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


def test_ply_table_is_raw_rows_and_skips_dropped(tmp_path):
    clean, path = tmp_path / "clean.ply", tmp_path / "s.ply"
    write_surfel_ply(clean, _scene())
    ply = plyfile.PlyData.read(str(clean), mmap=False)
    ply["vertex"].data["x"][[3, 7]] = np.nan  # dropped on load
    ply.write(str(path))
    scene = load_scene(path)
    table = surfel_point_table(scene)
    rows = plyfile.PlyData.read(str(path), mmap=False)["vertex"].data
    kept = np.setdiff1d(np.arange(50), [3, 7])
    np.testing.assert_array_equal(table.columns["divas_index"], kept)
    for name in rows.dtype.names:
        np.testing.assert_array_equal(table.columns[name], rows[name][kept])
    assert list(table.columns)[-4:] == list(ENGINE_COLUMNS)
    assert all(v.flags.c_contiguous for v in table.columns.values())


def test_decoded_columns_invert_the_activations():
    s = _scene()
    cols = decoded_columns(s)
    np.testing.assert_allclose(1 / (1 + np.exp(-cols["opacity"])), s.opacities, rtol=1e-5)
    np.testing.assert_allclose(np.exp(cols["scale_0"]), s.scales[:, 0], rtol=1e-6)
    assert [f"f_rest_{i}" in cols for i in range(9)] == [True] * 9
    np.testing.assert_array_equal(cols["f_rest_3"], s.sh[:, 1, 1])  # channel-major


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

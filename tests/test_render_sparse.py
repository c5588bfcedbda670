"""A value render of a few surfels with only the surfels that can blend before them
(:meth:`SurfelRenderer.render_values_sparse`, :mod:`divas_engine.render.surfel_blocks`)
is the dense render, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.render.config import RenderConfig
from divas_engine.render.surfel_blocks import SurfelBlocks, ball_pixel_bounds
from divas_engine.render.surfel_renderer import SurfelRenderer
from tests.reference_render import random_surfel_scene


@pytest.fixture(scope="module")
def case():
    # surfels on both sides of the near plane, large and small, overlapping in depth
    sc = random_surfel_scene(3000, seed=4, z_range=(-0.5, 6.0), scale_range=(0.01, 0.3))
    cam = Camera.look_at(
        [0.2, -0.1, -0.3], [0, 0, 4], [0, -1, 0], width=96, height=72, fx=80, cx=48.3, cy=35.7
    )
    return sc, cam


def _dense(n: int, rows: np.ndarray, vals: np.ndarray) -> np.ndarray:
    out = np.zeros((n, vals.shape[1]), np.float32)
    out[rows] = vals
    return out


@pytest.mark.parametrize("which", ["near", "middle", "far", "random"])
def test_sparse_value_render_is_the_dense_render(case, which):
    """Rows in front, in a middle depth band (occluders in front and behind), at the
    back, scattered; whole image and a crop, ``[K]`` and ``[K,C]`` values."""
    sc, cam = case
    r = SurfelRenderer(sc, device="cpu")
    z = cam.world_to_camera(sc.means)[:, 2]
    rng = np.random.default_rng(0)
    pick = {
        "near": (z > 0.5) & (z < 1.5),
        "middle": (z > 3.0) & (z < 3.6),
        "far": z > 5.5,
        "random": rng.random(len(z)) < 0.05,
    }[which]
    rows = np.flatnonzero(pick)
    vals = rng.uniform(0.2, 1.0, (len(rows), 2)).astype(np.float32)
    for c in (cam, cam.cropped(20, 11, 41, 37)):
        dense = r.render_values(c, _dense(len(sc), rows, vals))
        assert np.abs(dense).max() > 1e-5  # the rows show (through what is in front)
        assert np.array_equal(r.render_values_sparse(c, rows, vals), dense)
        one = r.render_values_sparse(c, rows, vals[:, 0])
        assert one.shape == (c.height, c.width) and np.array_equal(one, dense[..., 0])


def test_sparse_render_leaves_out_what_is_behind(case):
    """The rows' render needs what is in front of them: blocks wholly behind the rows'
    depth (or off the image) are left out, and those in front kept."""
    sc, cam = case
    r = SurfelRenderer(sc, device="cpu", config=RenderConfig())
    r.render_values_sparse(cam, np.zeros(0, np.int64), np.zeros((0, 1), np.float32))
    blocks, reach = r.sparse_index()
    z = cam.world_to_camera(sc.means)[:, 2]
    rows = np.flatnonzero((z > 1.0) & (z < 1.3))
    kept = blocks.near(cam, sc.means[rows], reach[rows], 3.0)
    assert set(rows) <= set(kept.tolist())
    assert np.all(np.diff(kept) > 0)
    assert np.count_nonzero(z[kept] > 3.0) < 0.2 * np.count_nonzero(z > 3.0)
    # no row on the image: nothing to render
    none = blocks.near(cam, sc.means[rows] + [0.0, 0.0, -10.0], reach[rows], 3.0)
    assert len(none) == 0


def test_ball_pixel_bounds_hold_the_ball(case):
    """Points on each ball's surface project inside its bounds; a ball across the camera
    plane is flagged."""
    _, cam = case
    rng = np.random.default_rng(1)
    c = np.c_[rng.uniform(-2, 2, (200, 2)), rng.uniform(0.3, 6, 200)]
    c = cam.c2w[:3, :3] @ c.T
    c = c.T + cam.c2w[:3, 3]
    rad = rng.uniform(0.01, 0.5, 200)
    lo, hi, front, cut = ball_pixel_bounds(cam, c, rad)
    d = rng.normal(size=(200, 64, 3))
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    for i in np.flatnonzero(front):
        uv, zz = cam.project(c[i] + rad[i] * d[i])
        assert np.all(zz > 0)
        assert np.all(uv >= lo[i] - 1e-9) and np.all(uv <= hi[i] + 1e-9)
    zc = cam.world_to_camera(c)[:, 2]
    assert np.array_equal(cut, (zc - rad <= 0) & (zc + rad > 0))


def test_blocks_cover_every_surfel():
    p = np.random.default_rng(2).uniform(-3, 3, (5000, 3))
    b = SurfelBlocks.build(p, np.full(5000, 0.05))
    assert np.array_equal(np.sort(b.order), np.arange(5000))
    for k in range(len(b.start) - 1):
        m = p[b.order[b.start[k] : b.start[k + 1]]]
        assert np.all(np.linalg.norm(m - b.centre[k], axis=1) + 0.05 <= b.radius[k])


def test_near_in_row_blocks_is_the_same_map(case, monkeypatch):
    """``near`` takes the per-tile depth max over blocks of its rows (bounded memory at
    3M surfels): the rows kept equal those of one pass over all of them."""
    from divas_engine.render import surfel_blocks

    sc, cam = case
    r = SurfelRenderer(sc, device="cpu")
    blocks, reach = r.sparse_index()
    z = cam.world_to_camera(sc.means)[:, 2]
    out = {}
    for chunk in (1 << 30, 7):
        monkeypatch.setattr(surfel_blocks, "_NEAR_CHUNK", chunk)
        out[chunk] = [
            blocks.near(cam, sc.means[rows], reach[rows], r._margin_px)
            for rows in (np.flatnonzero((z > 2.0) & (z < 4.0)), np.flatnonzero(z > 5.0))
        ]
    for a, b in zip(out[1 << 30], out[7]):
        assert 0 < len(a) < len(sc)
        np.testing.assert_array_equal(a, b)

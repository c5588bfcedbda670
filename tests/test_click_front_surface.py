"""The surface a click lands on: the pixel's median depth, unless a nearer surface draws at
least a third of the pixel (a thin object in front of a background). Hand-made layers of
camera-facing surfels with known opacities; the expected depths are their planes'."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.render import make_renderer
from divas_engine.scene import SurfelScene
from divas_engine.session import SessionConfig
from divas_engine.session.backends import SurfelBackend
from divas_engine.views.config import ViewConfig

_WALL_Z, _FRONT_Z = 2.0, 1.7  # planar depths of the two layers (the camera looks down +y)


def _layers(front_opacity: float, front_z: float | tuple = _FRONT_Z) -> SurfelScene:
    """A wall (an opaque grid of wide camera-facing surfels) and, in front of it on the
    clicked ray, one surfel of the given opacity; the camera at the origin looks along +y."""
    g = np.linspace(-0.3, 0.3, 13)
    xs, zs = np.meshgrid(g, g)
    grid = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1)
    zs = np.atleast_1d(np.asarray(front_z, float))  # surfels on the clicked ray (a spoke)
    front = np.stack([np.zeros(len(zs)), zs, np.zeros(len(zs))], 1)
    means = np.concatenate([grid + [0, _WALL_Z, 0], front]).astype(np.float32)
    n = len(means)
    # normal (rotation column 2) along y: a rotation of 90° about x
    quats = np.tile(np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0], np.float32), (n, 1))
    scales = np.full((n, 2), 0.04, np.float32)
    opac = np.r_[np.full(len(grid), 0.999), np.full(len(zs), front_opacity)].astype(np.float32)
    sh = np.zeros((n, 1, 3), np.float32)
    return SurfelScene(means, quats, scales, opac, sh, 0)


def _camera() -> Camera:
    return Camera.look_at(
        np.zeros(3),
        np.array([0.0, 1.0, 0.0]),
        np.array([0.0, 0.0, 1.0]),
        width=64,
        height=48,
        fx=60.0,
    )


def _depths(scene: SurfelScene, view: ViewConfig | None = None) -> tuple[float, float | None]:
    cfg = SessionConfig() if view is None else SessionConfig(view=view)
    renderer = make_renderer(scene, device="cpu")
    backend = SurfelBackend(scene, cfg, forward_facing=True, device="cpu", renderer=renderer)
    cam = _camera()
    b = renderer.render(cam)
    xy = (32.5, 24.5)
    return float(b.D_med[24, 32]), backend.click_depth_at(cam, xy, b)


@pytest.mark.parametrize("front", [0.41, 0.45])
def test_a_front_layer_drawing_a_third_of_the_pixel_is_the_one_clicked(front):
    d_med, z = _depths(_layers(front))
    assert d_med == pytest.approx(_WALL_Z, abs=1e-3)  # the median depth: the wall behind
    assert z == pytest.approx(_FRONT_Z, abs=1e-3)


def test_a_faint_front_layer_or_one_surface_keeps_the_median_depth():
    d_med, z = _depths(_layers(0.25))  # draws less than a third: the wall
    assert d_med == pytest.approx(_WALL_Z, abs=1e-3) and z is None
    d_med, z = _depths(_layers(0.6))  # draws more than half: D_med is already on it
    assert d_med == pytest.approx(_FRONT_Z, abs=1e-3) and z is None
    # a layer 1 % in front of the wall is the same surface (front_gap 2 %)
    d_med, z = _depths(_layers(0.41, front_z=_WALL_Z * 0.99))
    assert z is None
    # the rule off (a share of a half or more: D_med's own rule)
    _, z = _depths(_layers(0.41), ViewConfig(front_share=0.5))
    assert z is None


def test_faint_haze_spread_in_depth_is_no_surface():
    """Four faint splats in front (α 0.12 each, 0.2 apart in depth) together draw 0.4 of
    the pixel before the wall, but no depth band of them draws a third: the wall."""
    d_med, z = _depths(_layers(0.12, front_z=(0.9, 1.1, 1.3, 1.5)))
    assert d_med == pytest.approx(_WALL_Z, abs=1e-3) and z is None
    # the same four packed within the band are one translucent surface: it is clicked
    d_med, z = _depths(_layers(0.12, front_z=(1.7, 1.705, 1.71, 1.715)))
    assert d_med == pytest.approx(_WALL_Z, abs=1e-3) and 1.69 < z < 1.72

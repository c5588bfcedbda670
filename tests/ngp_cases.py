"""Small instant-ngp snapshots for the tests, built with the engine's field-by-field writer
(:mod:`divas_engine.io.instant_ngp_writer`, which follows ``Testbed::save_snapshot``)."""

from __future__ import annotations

import copy

import numpy as np

from divas_engine.camera import Camera
from divas_engine.io.instant_ngp import NgpFrame
from divas_engine.io.instant_ngp_writer import BASE_CONFIG, cascade_centres, snapshot_document

__all__ = ["small_config", "sphere_snapshot", "look_at_camera"]


def small_config(levels: int = 4, log2_t: int = 10, width: int = 16) -> dict:
    """``configs/nerf/base.json`` made small: hashed fine levels, dense coarse ones."""
    cfg = copy.deepcopy(BASE_CONFIG)
    cfg["encoding"].update(
        n_levels=levels, n_features_per_level=4, log2_hashmap_size=log2_t, base_resolution=4
    )
    cfg["encoding"]["per_level_scale"] = 2.0
    cfg["network"]["n_neurons"] = width
    cfg["rgb_network"]["n_neurons"] = width
    return cfg


def look_at_camera(eye, target, size=(64, 48), f=60.0, name="cam") -> Camera:
    """An OpenCV camera at ``eye`` looking at ``target`` (world up +z)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, y, z], 1)
    c2w[:3, 3] = eye
    w, h = size
    return Camera(w, h, f, f, w / 2, h / 2, c2w, name)


def sphere_snapshot(
    centre_world=(0.3, -0.2, 0.1),
    radius_world: float = 0.3,
    thickness: float = 0.5,
    frame: NgpFrame | None = None,
    aabb_scale: int = 1,
    network=None,
    config=None,
    cameras=None,
    unseen_corner: bool = True,
) -> tuple[dict, NgpFrame]:
    """A snapshot whose density grid is a ball (optical thickness ``thickness`` per cell),
    with cells of one corner marked unseen (−1) like instant-ngp's untrained cells."""
    frame = frame or NgpFrame(0.33, (0.5, 0.5, 0.5))
    _, cen = cascade_centres(aabb_scale)
    c = frame.to_ngp(np.asarray(centre_world, float))
    d = np.linalg.norm(cen - c, axis=-1)
    ot = np.where(d < radius_world * frame.scale, thickness, 0.0).astype(np.float32)
    if unseen_corner:
        ot[:, :8, :8, :8] = -1.0
    doc = snapshot_document(
        ot, frame, aabb_scale, cameras=cameras or [], network=network, config=config
    )
    return doc, frame

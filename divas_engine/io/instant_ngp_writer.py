"""Build instant-ngp snapshots field by field, as ``Testbed::save_snapshot`` does.

Follows ``NVlabs/instant-ngp`` ``src/testbed.cu`` l. 5288-5355 (the snapshot map, in that
order: trainer state, ``version``, ``mode``, ``density_grid_size``, ``density_grid_binary``,
``nerf.{aabb_scale, cam_pos_offset, cam_rot_offset, extra_dims_opt}``, ``training_step``,
``loss``, ``aabb``, ``bounding_radius``, ``render_aabb_to_local``, ``render_aabb``,
``up_dir``, ``sun_dir``, ``exposure``, ``background_color``, ``camera.{…}``, ``nerf.rgb.{…}``,
``nerf.dataset``), tiny-cuda-nn's ``Trainer::serialize`` (``trainer.h`` l. 442-452:
``n_params``, ``params_type``, ``params_binary``) and ``json_binding.h`` l. 112-136 for the
dataset. Matrices are lists of rows (``tiny-cuda-nn/vec_json.h``); binary values are msgpack
``bin``. Reading needs none of this: it makes snapshots of generated scenes (tests, the suite).
"""

from __future__ import annotations

import copy
import math

import numpy as np

from ..camera import Camera
from .instant_ngp import NERF_CASCADES, NERF_GRIDSIZE, SNAPSHOT_FORMAT_VERSION, STEPSIZE, NgpFrame
from .ngp_cascades import CascadeLayout, dense_to_morton
from .ngp_network import NgpNetwork, pack_params

__all__ = [
    "BASE_CONFIG",
    "snapshot_document",
    "cascade_centres",
    "max_cascade_for",
    "optical_thickness_of",
]

#: ``configs/nerf/base.json`` (its optimiser and loss too: they are part of every snapshot)
BASE_CONFIG: dict = {
    "loss": {"otype": "Huber"},
    "optimizer": {
        "otype": "Ema",
        "decay": 0.95,
        "nested": {
            "otype": "ExponentialDecay",
            "decay_start": 20000,
            "decay_interval": 10000,
            "decay_base": 0.33,
            "nested": {
                "otype": "Adam",
                "learning_rate": 1e-2,
                "beta1": 0.9,
                "beta2": 0.99,
                "epsilon": 1e-15,
                "l2_reg": 1e-6,
            },
        },
    },
    "encoding": {
        "otype": "HashGrid",
        "n_levels": 8,
        "n_features_per_level": 4,
        "log2_hashmap_size": 19,
        "base_resolution": 16,
    },
    "network": {
        "otype": "FullyFusedMLP",
        "activation": "ReLU",
        "output_activation": "None",
        "n_neurons": 64,
        "n_hidden_layers": 1,
    },
    "dir_encoding": {
        "otype": "Composite",
        "nested": [
            {"n_dims_to_encode": 3, "otype": "SphericalHarmonics", "degree": 4},
            {"otype": "Identity"},
        ],
    },
    "rgb_network": {
        "otype": "FullyFusedMLP",
        "activation": "ReLU",
        "output_activation": "None",
        "n_neurons": 64,
        "n_hidden_layers": 2,
    },
}


def max_cascade_for(aabb_scale: int) -> int:
    """``testbed_nerf.cu`` l. 2433-2436."""
    return max(0, math.ceil(math.log2(int(aabb_scale))))


def cascade_centres(aabb_scale: int) -> tuple[CascadeLayout, np.ndarray]:
    """The layout and ``[C, R, R, R, 3]`` NeRF-frame centres of every cell (``[x, y, z]``)."""
    C = max_cascade_for(aabb_scale) + 1
    lay = CascadeLayout(C, NERF_GRIDSIZE, (0.5, 0.5, 0.5), 0.5)
    i = np.arange(NERF_GRIDSIZE) + 0.5
    out = np.empty((C, NERF_GRIDSIZE, NERF_GRIDSIZE, NERF_GRIDSIZE, 3), np.float32)
    for m in range(C):
        ax = lay.lo(m)[0] + i * lay.cell(m)
        X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
        out[m] = np.stack([X, Y, Z], -1)
    return lay, out


def _xform(cam: Camera, frame: NgpFrame) -> list[list[float]]:
    """A training camera as instant-ngp keeps it: NeRF frame, x right / y down / z fwd."""
    M = np.zeros((3, 4))
    M[:, :3] = cam.c2w[:3, :3][list(frame.axes), :]
    M[:, 3] = frame.to_ngp(cam.c2w[:3, 3])
    return M.tolist()


def _dataset(frame: NgpFrame, aabb_scale: int, cameras: list[Camera], render_aabb) -> dict:
    """``to_json(NerfDataset)``, ``json_binding.h`` l. 112-136."""
    meta, xforms = [], []
    for c in cameras:
        meta.append(
            {
                "focal_length": [float(c.fx), float(c.fy)],
                "lens": None,  # a perspective Lens writes nothing (json_binding.h l. 37-65)
                "principal_point": [float(c.cx / c.width), float(c.cy / c.height)],
                "rolling_shutter": [0.0, 0.0, 0.0, 0.0],
                "resolution": [int(c.width), int(c.height)],
            }
        )
        x = _xform(c, frame)
        xforms.append({"start": x, "end": x})
    return {
        "n_images": len(cameras),
        "paths": [f"{c.name or f'image_{i:04d}'}.png" for i, c in enumerate(cameras)],
        "metadata": meta,
        "xforms": xforms,
        "render_aabb": render_aabb,
        "render_aabb_to_local": np.eye(3).tolist(),
        "up": [0.0, 1.0, 0.0],
        "offset": [float(v) for v in frame.offset],
        "envmap_resolution": [0, 0],
        "scale": float(frame.scale),
        "aabb_scale": int(aabb_scale),
        "from_mitsuba": bool(frame.from_mitsuba),
        "is_hdr": False,
        "wants_importance_sampling": True,
        "n_extra_learnable_dims": 0,
    }


def snapshot_document(
    optical_thickness: np.ndarray,
    frame: NgpFrame,
    aabb_scale: int,
    *,
    cameras: list[Camera] | None = None,
    network: NgpNetwork | None = None,
    config: dict | None = None,
    params_type: str = "__half",
    training_step: int = 0,
) -> dict:
    """The msgpack document instant-ngp would save for this grid and network.

    Args:
        optical_thickness: ``[C, 128, 128, 128]`` per cascade, ``[x, y, z]`` (σ·STEPSIZE,
            −1 for cells no camera sees), ``C = max_cascade + 1``.
        network: its parameters become ``params_binary`` (``config`` must describe it);
            None: no trainer state (a grid-only snapshot).
        config: the network config (default :data:`BASE_CONFIG`).
    """
    C = max_cascade_for(aabb_scale) + 1
    grid = np.asarray(optical_thickness, np.float32)
    if grid.shape != (C, NERF_GRIDSIZE, NERF_GRIDSIZE, NERF_GRIDSIZE):
        raise ValueError(f"expected {C} cascades of 128³, got {grid.shape}")
    cameras = list(cameras or [])
    doc = copy.deepcopy(config if config is not None else BASE_CONFIG)
    half = 0.5 * min(1 << (NERF_CASCADES - 1), int(aabb_scale))
    aabb = {"min": [0.5 - half] * 3, "max": [0.5 + half] * 3}
    snap: dict = {}
    if network is not None:  # Trainer::serialize
        p = pack_params(network)
        dt = "<f2" if params_type == "__half" else "<f4"
        snap.update(n_params=int(p.size), params_type=params_type)
        snap["params_binary"] = p.astype(dt).tobytes()
    snap["version"] = SNAPSHOT_FORMAT_VERSION
    snap["mode"] = "Nerf"
    snap["density_grid_size"] = NERF_GRIDSIZE
    snap["density_grid_binary"] = dense_to_morton(grid).astype("<f2").tobytes()
    snap["nerf"] = {
        "aabb_scale": int(aabb_scale),
        "cam_pos_offset": [],
        "cam_rot_offset": [],
        "extra_dims_opt": [],
    }
    snap["training_step"] = int(training_step)
    snap["loss"] = 0.0
    snap["aabb"] = aabb
    snap["bounding_radius"] = 1.0
    snap["render_aabb_to_local"] = np.eye(3).tolist()
    snap["render_aabb"] = aabb
    snap["up_dir"] = [0.0, 1.0, 0.0]
    snap["sun_dir"] = (np.array([0.5, 0.5, 0.5]) / math.sqrt(0.75)).tolist()
    snap["exposure"] = 0.0
    snap["background_color"] = [0.0, 0.0, 0.0, 1.0]
    cam0 = np.eye(4)[:3] if not cameras else np.asarray(_xform(cameras[0], frame))
    snap["camera"] = {
        "matrix": np.asarray(cam0).tolist(),
        "fov_axis": 1,
        "relative_focal_length": [1.0, 1.0],
        "screen_center": [0.5, 0.5],
        "zoom": 1.0,
        "scale": 1.0,
        "aperture_size": 0.0,
        "autofocus": False,
        "autofocus_target": [0.5, 0.5],
        "autofocus_depth": 1.0,
    }
    snap["nerf"]["rgb"] = {
        "rays_per_batch": 1 << 12,
        "measured_batch_size": 0,
        "measured_batch_size_before_compaction": 0,
    }
    snap["nerf"]["dataset"] = _dataset(frame, aabb_scale, cameras, aabb)
    doc["snapshot"] = snap
    return doc


def optical_thickness_of(sigma_world: np.ndarray, frame: NgpFrame) -> np.ndarray:
    """Optical thickness of the smallest step for σ per training-frame unit."""
    return np.asarray(sigma_world, np.float32) / np.float32(frame.scale) * np.float32(STEPSIZE)

"""One fused view: host buffers, validation and the per-view device preprocessing
(integral images, depth-gradient factor) shared by the 2DGS and NeRF fusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from divas_kernels.fusion_common import ViewData, depth_gradient_factor
from divas_kernels.integral_image import integral_images

from ..camera import Camera

__all__ = ["FusionView", "upload_view"]


@dataclass(eq=False)
class FusionView:
    """The inputs of one view to the fusion kernels (Sec. 3.5, alg:gs-fusion, alg:nerf-fusion).

    Attributes:
        camera: the view's :class:`Camera` (OpenCV, +0.5 pixel centres).
        mask: ``[H,W]`` refined mask probabilities M̃ in [0,1].
        d_min, d_ref, d_max: ``[H,W]`` planar depths (D_ref = D_med for 2DGS, D_exp for
            NeRF); 0 = invalid.
        n_samp: ``[H,W]`` N_samp counts (any numeric dtype; rounded to int32).
        d_cam: camera-to-target distance (NOTES: orbit radius for centroid views,
            distance to the look-at point otherwise). Used by the 2DGS see-through test.
        name: free-form label.
    """

    camera: Camera
    mask: np.ndarray
    d_min: np.ndarray
    d_ref: np.ndarray
    d_max: np.ndarray
    n_samp: np.ndarray
    d_cam: float = 0.0
    name: str = ""

    def __post_init__(self) -> None:
        shape = (self.camera.height, self.camera.width)
        for k in ("mask", "d_min", "d_ref", "d_max", "n_samp"):
            a = np.asarray(getattr(self, k))
            if a.shape != shape:
                raise ValueError(
                    f"FusionView {self.name!r}: {k} has shape {a.shape}, "
                    f"expected {shape} from the camera"
                )
            if k != "n_samp" and not np.all(np.isfinite(a)):
                raise ValueError(f"FusionView {self.name!r}: {k} contains NaN/Inf")
            setattr(self, k, a)
        m = self.mask
        if m.size and (m.min() < 0.0 or m.max() > 1.0):
            raise ValueError(f"FusionView {self.name!r}: mask must hold probabilities in [0,1]")
        if not np.isfinite(self.d_cam) or self.d_cam < 0:
            raise ValueError(f"FusionView {self.name!r}: d_cam={self.d_cam} must be ≥ 0 and finite")


def upload_view(view: FusionView, *, mask_pos: float, k_dg: float, eps: float, device) -> ViewData:
    """Copy a view to ``device`` and precompute its integral images and π_dg."""
    cam = view.camera
    w2c = cam.w2c

    def f32(a: np.ndarray) -> wp.array2d:
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=float, device=device)

    v = ViewData()
    v.rot = wp.mat33(*w2c[:3, :3].astype(np.float32).ravel())
    v.trans = wp.vec3(*w2c[:3, 3].astype(np.float32))
    v.origin = wp.vec3(*cam.center.astype(np.float32))
    v.fx, v.fy, v.cx, v.cy = float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)
    v.rot_d = wp.mat33d(*w2c[:3, :3].ravel())
    v.trans_d = wp.vec3d(*w2c[:3, 3])
    v.origin_d = wp.vec3d(*cam.center)
    v.fx_d, v.fy_d = wp.float64(cam.fx), wp.float64(cam.fy)
    v.cx_d, v.cy_d = wp.float64(cam.cx), wp.float64(cam.cy)
    v.width, v.height = int(cam.width), int(cam.height)
    v.d_cam = float(view.d_cam)
    v.mask = f32(view.mask)
    v.dmin, v.dref, v.dmax = f32(view.d_min), f32(view.d_ref), f32(view.d_max)
    n = np.rint(np.nan_to_num(np.asarray(view.n_samp, dtype=np.float64))).clip(0, 2**31 - 1)
    v.nsamp = wp.array(n.astype(np.int32), dtype=wp.int32, device=device)
    v.sat_n, v.sat_n2, v.sat_pos = integral_images(v.nsamp, v.mask, mask_pos, device=device)
    v.pdg = depth_gradient_factor(v.dmin, v.dref, v.dmax, k_dg, eps, device=device)
    return v

"""One fused view: host buffers, validation and the per-view device preprocessing
(integral images, depth-gradient factor) shared by the 2DGS and NeRF fusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_kernels import ViewData, upload_view_data

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
    n = np.rint(np.nan_to_num(np.asarray(view.n_samp, dtype=np.float64))).clip(0, 2**31 - 1)
    return upload_view_data(
        cam.w2c,
        cam.center,
        (cam.fx, cam.fy, cam.cx, cam.cy),
        view.d_cam,
        view.mask,
        view.d_min,
        view.d_ref,
        view.d_max,
        n.astype(np.int32),
        mask_pos=mask_pos,
        k_dg=k_dg,
        eps=eps,
        device=device,
    )

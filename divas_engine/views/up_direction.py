"""Scene up direction and capture type from the training cameras (paper Sec. 3.2;
NOTES "Anchors").

* Mean of the cameras' image-up vectors (−y of the OpenCV camera).
* Capture type: forward-facing when the cameras look the same way — the mean
  resultant length of their unit optical axes is ≥ ``forward_facing_resultant``
  (0.9 ≈ all within ~25° of the mean); otherwise 360° (rings, half rings, domes).
* 360° captures: the mean is refined to the normal of the best-fit plane of the
  camera centres (smallest right-singular vector of the centred centres), oriented
  to agree with the mean — but only when that plane is well defined (smallest /
  middle singular value ≤ ``plane_flatness``) and the normal lies within
  ``plane_max_tilt_deg`` of the mean up; otherwise the mean is kept. The guard
  rejects degenerate rigs (a camera line, a sphere of cameras) whose "plane"
  normal is noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from .config import ViewConfig

__all__ = ["UpEstimate", "estimate_up"]


@dataclass(frozen=True)
class UpEstimate:
    """Result of :func:`estimate_up`.

    Attributes:
        up: unit scene up [3].
        mean_up: normalised mean of the camera up vectors [3].
        forward_facing: capture type (False: 360°).
        resultant: mean resultant length of the optical axes (1 = all parallel).
        plane_used: the plane normal replaced the mean.
        plane_tilt_deg: angle between plane normal and mean up (NaN if not computed).
    """

    up: np.ndarray
    mean_up: np.ndarray
    forward_facing: bool
    resultant: float
    plane_used: bool
    plane_tilt_deg: float


def estimate_up(cameras: list[Camera], config: ViewConfig | None = None) -> UpEstimate:
    """Scene up and capture type of a training-camera set (≥ 1 camera)."""
    cfg = config or ViewConfig()
    if not cameras:
        raise ValueError("estimate_up: no cameras")
    ups = np.stack([c.up for c in cameras])
    mean_up = ups.mean(0)
    if np.linalg.norm(mean_up) < 1e-9:
        raise ValueError("estimate_up: the cameras' up vectors cancel out")
    mean_up /= np.linalg.norm(mean_up)
    fwd = np.stack([c.forward for c in cameras])
    resultant = float(np.linalg.norm(fwd.mean(0)))
    forward_facing = resultant >= cfg.forward_facing_resultant
    up, used, tilt = mean_up, False, float("nan")
    if not forward_facing and len(cameras) >= 3:
        centres = np.stack([c.center for c in cameras])
        _, s, vt = np.linalg.svd(centres - centres.mean(0), full_matrices=False)
        if s.shape[0] == 3 and s[1] > 0:
            n = vt[2] if vt[2] @ mean_up >= 0 else -vt[2]
            tilt = math.degrees(math.acos(float(np.clip(n @ mean_up, -1.0, 1.0))))
            if s[2] / s[1] <= cfg.plane_flatness and tilt <= cfg.plane_max_tilt_deg:
                up, used = n / np.linalg.norm(n), True
    return UpEstimate(up, mean_up, forward_facing, resultant, used, tilt)

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

Without cameras (:func:`estimate_scene_up`; not in the paper, issue 17) the up comes
from the scene itself, first rule that applies:

1. ``override`` — the user's ``--up`` / ``ViewConfig.up``; confidence 1.
2. ``ground`` — a supporting ground plane (:func:`~.ground.ground_candidates`, with
   support ≥ ``ground_min_support`` and sharpness ≥ ``ground_min_sharpness``) that
   either (a) lies within ``ground_convention_deg`` of the pipeline convention
   (``convention_up``; the ground refines it), the strongest such one, or (b) is the
   strongest candidate of all, within ``ground_axis_deg`` of a world axis and covering
   ≥ ``ground_min_coverage`` of the content's footprint — a file someone re-oriented
   with its floor on an axis (Z-up tiles, Y-up glTF exports). Rule (b) goes first. A
   dense one-sided plane elsewhere (the face of a guitar against its stand) is not
   taken. A ground normal within ``ground_snap_deg`` (10°) of a world axis is snapped
   to that axis: files are axis-aligned far more often than not (an editor such as
   SuperSplat levels them, a converter puts the floor on an axis), and the contact
   band of a capture — its underside, the part its cameras saw least — is itself only
   good to a few degrees (measured on the shared captures over 8 seeds: the biker's
   soles 4.8–8.3° from the upright the body shows, the guitar stand's feet 3.7–4.5°
   from the level its leg bars show, the LOD tiles 0.5°, the SOG playbot 0.2° and
   logo 1.2–2.1°).
   Confidence 0.5 + 0.5 · sharpness: two cues agree (a one-sided contact plane and
   the convention or the axis alignment), weighted by how planar the contact is.
3. ``convention`` — ``convention_up`` (COLMAP-trained captures: −y); confidence 0.3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from ..camera import Camera
from .config import ViewConfig
from .ground import GroundPlane, ground_candidates

__all__ = [
    "UpEstimate",
    "estimate_up",
    "UpSource",
    "SceneUp",
    "estimate_scene_up",
    "snap_to_axis",
]

CONVENTION_CONFIDENCE = 0.3


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


class UpSource(StrEnum):
    """Where a scene up came from (:func:`estimate_scene_up`, training cameras)."""

    OVERRIDE = "override"
    CAMERAS = "cameras"
    GROUND = "ground"
    CONVENTION = "convention"


@dataclass(frozen=True, eq=False)
class SceneUp:
    """The scene up of a capture and how sure we are of it.

    Attributes:
        up: unit scene up [3].
        source: :class:`UpSource`.
        confidence: in [0, 1] (rules in the module docstring).
        ground: the supporting plane used (None unless ``source`` is ``ground``) —
            also kept with an override when a ground was found along that up.
        reason: one line for ``divas info`` / ``divas anchors``.
        candidates: every supporting-plane candidate examined.
    """

    up: np.ndarray
    source: UpSource
    confidence: float
    ground: GroundPlane | None
    reason: str
    candidates: tuple[GroundPlane, ...] = ()

    def to_dict(self) -> dict:
        return {
            "up": self.up.tolist(),
            "source": str(self.source),
            "confidence": self.confidence,
            "reason": self.reason,
            "ground": None if self.ground is None else self.ground.to_dict(),
        }


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def snap_to_axis(v: np.ndarray, max_deg: float) -> tuple[np.ndarray, float]:
    """``v`` replaced by the nearest signed world axis when within ``max_deg`` of it;
    returns ``(vector, angle to that axis in degrees)``."""
    v = _unit(v)
    k = int(np.argmax(np.abs(v)))
    axis = np.zeros(3)
    axis[k] = math.copysign(1.0, v[k])
    ang = _angle_deg(v, axis)
    return (axis if ang <= max_deg else v), ang


def _ground_up(g: GroundPlane, cfg: ViewConfig, why: str, cands) -> SceneUp:
    up, ang = snap_to_axis(g.normal, cfg.ground_snap_deg)
    snapped = ang <= cfg.ground_snap_deg
    note = f"; snapped to the world axis {ang:.1f}° away" if snapped else ""
    return SceneUp(up, UpSource.GROUND, 0.5 + 0.5 * g.sharpness, g, why + note, cands)


def estimate_scene_up(
    points: np.ndarray,
    weights: np.ndarray,
    center: np.ndarray,
    r_fg: float,
    config: ViewConfig | None = None,
    up: np.ndarray | None = None,
) -> SceneUp:
    """Scene up of a capture without cameras (module docstring rules).

    Args:
        points, weights: Gaussian centres and opacities (:func:`~.ground.scene_points`).
        center, r_fg: ``c_scene`` and ``r_fg`` of the scene.
        up: an explicit up (wins over ``config.up``).
    """
    cfg = config or ViewConfig()
    cands = tuple(ground_candidates(points, weights, center, r_fg, cfg))
    override = up if up is not None else cfg.up
    if override is not None:
        u = _unit(override)
        along = [g for g in cands if _angle_deg(g.normal, u) <= cfg.ground_convention_deg]
        g = max(along, key=lambda g: g.support) if along else None
        return SceneUp(u, UpSource.OVERRIDE, 1.0, g, "given (--up)", cands)
    conv = _unit(cfg.convention_up)
    good = [
        g
        for g in cands
        if g.support >= cfg.ground_min_support and g.sharpness >= cfg.ground_min_sharpness
    ]
    best = cands[0] if cands else None
    if (
        best is not None
        and best in good
        and best.axis_deg <= cfg.ground_axis_deg
        and best.coverage >= cfg.ground_min_coverage
    ):
        return _ground_up(
            best,
            cfg,
            f"ground plane on a world axis, covering {best.coverage:.0%} of the footprint",
            cands,
        )
    near = [g for g in good if _angle_deg(g.normal, conv) <= cfg.ground_convention_deg]
    if near:
        g = max(near, key=lambda g: g.support)
        return _ground_up(
            g,
            cfg,
            f"ground plane {_angle_deg(g.normal, conv):.1f}° from the capture convention",
            cands,
        )
    return SceneUp(
        conv,
        UpSource.CONVENTION,
        CONVENTION_CONFIDENCE,
        None,
        "no ground plane found; capture convention (COLMAP-trained: -y)",
        cands,
    )

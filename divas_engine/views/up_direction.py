"""Scene up direction and capture type from the training cameras (paper Sec. 3.2;
NOTES "Anchors").

With cameras: the mean of their image-up vectors (−y of the OpenCV camera); forward-facing
when the mean resultant length of their optical axes is ≥ ``forward_facing_resultant``, else
360°, where the mean is refined to the normal of the camera centres' best-fit plane when that
plane is well defined and within ``plane_max_tilt_deg`` of the mean.

Without cameras (:func:`estimate_scene_up`; not in the paper), first rule that applies:
``override`` (``--up`` / ``ViewConfig.up``, confidence 1); ``ground`` — a supporting plane
(:func:`~.ground.ground_candidates`) near the pipeline convention, or the strongest one when it
is axis-aligned and covers the content's footprint; snapped to a world axis within
``ground_snap_deg`` (files are usually axis-aligned and a contact band is good to only a few
degrees); confidence 0.5 + 0.5 · sharpness; ``convention`` (−y), confidence 0.3.
The rules in full: docs/design-notes.md.
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

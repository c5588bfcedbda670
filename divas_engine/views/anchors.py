"""Anchor views (paper Sec. 3.2, App. C.1–C.2; NOTES "Anchors").

Candidates: N Fibonacci directions (eq:fib) in the up-aligned frame around ``c_scene``, ranked
by alg:view_ranking. Radius: NeRF — the median training-camera distance; 2DGS (eq:gs-radius) —
``r_i = min(r_knn, r_cap)`` (mean distance of the ``knn_cameras`` nearest cameras, P90 of the
cameras in a 45° cone; none in the cone → ``unsupported``).

Capture types (:mod:`.up_direction`): 360° takes the top-K supported candidates;
forward-facing takes K training cameras spread over the rig (farthest-point order);
camera-free scenes (not in the paper, :func:`plan_scene_anchors`) estimate the up from the
scene and frame every candidate on the robust foreground (:mod:`.framing`), on a Fibonacci
lattice of the elevation zone above a found ground. Anchor cameras look at ``c_scene`` with
image-up = scene up. The rules in full: docs/design-notes.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from ..scene import DensityGrid, Scene, SurfelScene
from ..scene_stats import RobustFrame, robust_frame
from .config import ViewConfig
from .fibonacci import fibonacci_sphere, up_frame
from .framing import SceneLayout, framed_camera, layout_from_points, look_from
from .ground import scene_points, spherical_cap
from .ranking import Ranking, rank_directions
from .up_direction import SceneUp, UpEstimate, estimate_up

__all__ = [
    "Anchor",
    "AnchorPlan",
    "plan_anchors",
    "plan_scene_anchors",
    "training_anchor",
    "gs_anchor_radii",
    "representative_camera",
    "scene_frame",
    "scene_layout",
]


@dataclass(frozen=True, eq=False)
class Anchor:
    """One anchor view.

    Attributes:
        camera: the anchor camera (OpenCV convention).
        direction: unit world direction from ``c_scene`` to the camera centre.
        score: ranking score I_i (NaN for training anchors).
        unsupported: 2DGS direction with no training camera within the cap cone.
        source: ``"fibonacci"`` or ``"training"``.
        index: Fibonacci sample index, or training-camera index.
        radius: distance from ``c_scene`` to the camera.
    """

    camera: Camera
    direction: np.ndarray
    score: float
    unsupported: bool
    source: str
    index: int
    radius: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "camera": self.camera.to_dict(),
            "direction": self.direction.tolist(),
            "score": None if math.isnan(self.score) else float(self.score),
            "unsupported": bool(self.unsupported),
            "source": self.source,
            "index": int(self.index),
            "radius": float(self.radius),
        }


@dataclass(eq=False)
class AnchorPlan:
    """Anchors offered to the user plus everything they were derived from.

    Attributes:
        anchors: the offered anchors, in display order.
        candidates: all N Fibonacci anchors in sample order.
        ranking: scores of the candidates (:class:`~.ranking.Ranking`).
        center: ``c_scene``; up: scene up; frame: ``[3,3]`` up-aligned axes (columns).
        forward_facing, camera_free: capture type.
        up_estimate: the :class:`UpEstimate` (None when camera-free).
        layout: camera-free plans of a scene: the :class:`~.framing.SceneLayout` the
            anchors are framed on (its ``up`` is the :class:`~.up_direction.SceneUp`).
        intrinsics: the camera whose intrinsics the anchors use.
    """

    anchors: list[Anchor]
    candidates: list[Anchor]
    ranking: Ranking
    center: np.ndarray
    up: np.ndarray
    frame: np.ndarray
    forward_facing: bool
    camera_free: bool
    kind: str
    up_estimate: UpEstimate | None = None
    info: dict = field(default_factory=dict)
    layout: SceneLayout | None = None
    intrinsics: Camera | None = None

    @property
    def scene_up(self) -> SceneUp | None:
        """How the up of a camera-free scene plan was found (None otherwise)."""
        return None if self.layout is None else self.layout.up

    def frame_direction(
        self, direction: np.ndarray, name: str = "manual", config: ViewConfig | None = None
    ) -> Camera:
        """A camera for a user-chosen world direction (from the object towards the
        camera), framed like this plan's anchors — the manual "add anchor" path.

        Camera-free plans of a scene: :func:`~.framing.framed_camera`, the direction
        raised to ``ground_min_elevation_deg`` above the horizon when the scene has a
        ground. Otherwise: at the median candidate radius around ``center``, looking
        at it, image-up = the plan's up.
        """
        cfg = config or ViewConfig()
        d = np.asarray(direction, np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"frame_direction: bad direction {direction!r}")
        d = d / np.linalg.norm(d)
        intr = self.intrinsics or self.candidates[0].camera
        if self.layout is None:
            r = float(np.median([a.radius for a in self.candidates]))
            return _look(self.center, d, r, self.up, intr, name)
        if self.layout.floor is not None:
            d = _raise_above(d, self.up, cfg.ground_min_elevation_deg)
        return framed_camera(self.layout, d, intr, cfg, name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": 1,
            "kind": self.kind,
            "center": self.center.tolist(),
            "up": self.up.tolist(),
            "scene_up": None if self.scene_up is None else self.scene_up.to_dict(),
            "forward_facing": self.forward_facing,
            "camera_free": self.camera_free,
            "anchors": [a.to_dict() for a in self.anchors],
            "candidates": [a.to_dict() for a in self.candidates],
        }


def _raise_above(d: np.ndarray, up: np.ndarray, min_elevation_deg: float) -> np.ndarray:
    """``d`` with its elevation above the plane ⟂ ``up`` raised to ≥ the minimum."""
    s_min = math.sin(math.radians(min_elevation_deg))
    if d @ up >= s_min:
        return d
    horiz = d - (d @ up) * up
    if np.linalg.norm(horiz) < 1e-9:
        horiz = up_frame(up)[:, 0]
    horiz /= np.linalg.norm(horiz)
    return math.cos(math.asin(s_min)) * horiz + s_min * up


def scene_frame(scene: Scene) -> RobustFrame:
    """``c_scene`` and ``r_fg`` of a scene (density-weighted for NeRF grids)."""
    if isinstance(scene, SurfelScene):
        return robust_frame(scene.means)
    if isinstance(scene, DensityGrid):
        occ = scene.density > 0
        idx = np.argwhere(occ)[:, ::-1]
        centres = scene.aabb[0] + (idx + 0.5) * scene.voxel_size
        return robust_frame(centres, scene.density[occ])
    raise TypeError(f"scene_frame: unsupported scene type {type(scene).__name__}")


def scene_layout(
    scene: Scene, config: ViewConfig | None = None, up: np.ndarray | None = None
) -> SceneLayout:
    """The :class:`~.framing.SceneLayout` of a scene around :func:`scene_frame`: its up
    (``up`` / ``config.up`` / estimated) and robust foreground."""
    fr = scene_frame(scene)
    pts, w = scene_points(scene)
    return layout_from_points(pts, w, fr.center, fr.radius, config, up)


def representative_camera(cameras: list[Camera]) -> Camera:
    """The training camera with the median focal length (its intrinsics are reused)."""
    order = sorted(range(len(cameras)), key=lambda i: (cameras[i].fx, i))
    return cameras[order[len(order) // 2]]


def gs_anchor_radii(
    dirs: np.ndarray, center: np.ndarray, cam_centres: np.ndarray, config: ViewConfig | None = None
):
    """eq:gs-radius per world direction.

    Returns ``(r, r_knn, r_cap, unsupported)``, each ``[N]``; ``r_cap`` is +inf and
    ``r = r_knn`` where a direction is unsupported.
    """
    cfg = config or ViewConfig()
    rel = np.asarray(cam_centres, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    dist = np.linalg.norm(rel, axis=1)
    u = rel / np.maximum(dist, 1e-12)[:, None]
    d = np.asarray(dirs, dtype=np.float64)
    ang = np.degrees(np.arccos(np.clip(d @ u.T, -1.0, 1.0)))  # [N, M]
    k = min(cfg.knn_cameras, len(dist))
    nearest = np.argsort(ang, axis=1, kind="stable")[:, :k]
    r_knn = dist[nearest].mean(1)
    r_cap = np.full(len(d), np.inf)
    unsupported = np.zeros(len(d), dtype=bool)
    for i in range(len(d)):
        inside = ang[i] <= cfg.cap_cone_deg
        if inside.any():
            r_cap[i] = np.percentile(dist[inside], cfg.cap_percentile)
        else:
            unsupported[i] = True
    return np.minimum(r_knn, r_cap), r_knn, r_cap, unsupported


def _look(center, direction, radius, up, intr: Camera, name: str) -> Camera:
    return look_from(center + radius * direction, center, up, intr, name)


def training_anchor(cameras: list[Camera], key: int | str, center: np.ndarray) -> Anchor:
    """An anchor that is the training camera ``key`` (index or name) itself."""
    if isinstance(key, str):
        names = [c.name for c in cameras]
        if key not in names:
            raise KeyError(f"no training camera named {key!r}")
        idx = names.index(key)
    else:
        idx = int(key)
        if not 0 <= idx < len(cameras):
            raise KeyError(f"training camera index {idx} out of range 0..{len(cameras) - 1}")
    cam = cameras[idx]
    rel = cam.center - np.asarray(center, dtype=np.float64)
    r = float(np.linalg.norm(rel))
    return Anchor(cam, rel / max(r, 1e-12), float("nan"), False, "training", idx, r)


def _spread_training(cameras: list[Camera], k: int) -> list[int]:
    c = np.stack([cam.center for cam in cameras])
    first = int(np.argmin(np.linalg.norm(c - c.mean(0), axis=1)))
    chosen = [first]
    dmin = np.linalg.norm(c - c[first], axis=1)
    while len(chosen) < min(k, len(cameras)):
        nxt = int(np.argmax(dmin))
        if dmin[nxt] <= 0:
            break
        chosen.append(nxt)
        dmin = np.minimum(dmin, np.linalg.norm(c - c[nxt], axis=1))
    return chosen


def plan_anchors(
    center: np.ndarray,
    r_fg: float,
    cameras: list[Camera] | None,
    *,
    kind: SceneKind = SceneKind.GS2D,
    config: ViewConfig | None = None,
    all_views: bool = False,
    up: np.ndarray | None = None,
    layout: SceneLayout | None = None,
) -> AnchorPlan:
    """Anchor views of a scene (module docstring).

    Args:
        center, r_fg: ``c_scene`` and ``r_fg`` (:func:`scene_frame`).
        cameras: training cameras, or None/[] for the camera-free path.
        kind: ``SceneKind.GS2D`` (adaptive radius) or ``NERF`` (global radius).
        all_views: offer every Fibonacci candidate (ranked, unsupported included).
        up: override the scene up (default: ``config.up``, else estimated from the
            cameras; camera-free: the layout's up, else ``convention_up``).
        layout: camera-free: frame the anchors on this :class:`~.framing.SceneLayout`
            (its up wins over ``up``; build it with the override instead).
    """
    cfg = config or ViewConfig()
    if kind not in (SceneKind.GS2D, SceneKind.NERF):
        raise ValueError(f"plan_anchors: kind must be '2dgs' or 'nerf', got {kind!r}")
    center = np.asarray(center, dtype=np.float64)
    cameras = list(cameras or [])
    camera_free = not cameras
    est = None
    if up is None and cfg.up is not None:
        up = np.asarray(cfg.up, dtype=np.float64)
    if camera_free:
        if layout is not None:
            up_v = layout.up.up
        else:
            up_v = np.asarray(cfg.convention_up if up is None else up, dtype=np.float64)
        forward_facing = False
        front = None
        intr = Camera(
            cfg.fallback_width,
            cfg.fallback_height,
            cfg.fallback_fx,
            cfg.fallback_fx,
            cfg.fallback_width / 2.0,
            cfg.fallback_height / 2.0,
        )
    else:
        layout = None
        est = estimate_up(cameras, cfg)
        up_v = est.up if up is None else np.asarray(up, dtype=np.float64)
        forward_facing = est.forward_facing
        front = np.mean([c.center for c in cameras], axis=0) - center
        intr = representative_camera(cameras)
    up_v = up_v / np.linalg.norm(up_v)
    frame = up_frame(up_v, front)
    if layout is not None and layout.floor is not None:
        local = spherical_cap(
            np.array([0.0, 0.0, 1.0]),
            90.0 - cfg.ground_min_elevation_deg,
            cfg.n_fibonacci,
            90.0 - cfg.ground_max_elevation_deg,
        )
    else:
        local = fibonacci_sphere(cfg.n_fibonacci)
    dirs = local @ frame.T
    ranking = rank_directions(local, cfg)
    n = len(dirs)
    unsupported = np.zeros(n, dtype=bool)
    info: dict = {}
    if camera_free and layout is not None:
        cams = [framed_camera(layout, dirs[i], intr, cfg, f"fib_{i:02d}") for i in range(n)]
        radii = np.array([np.linalg.norm(c.center - layout.center) for c in cams])
    else:
        if camera_free:
            radii = np.full(n, cfg.fallback_radius_factor * float(r_fg))
        else:
            cc = np.stack([c.center for c in cameras])
            if kind == SceneKind.NERF:
                radii = np.full(n, float(np.median(np.linalg.norm(cc - center, axis=1))))
            else:
                radii, r_knn, r_cap, unsupported = gs_anchor_radii(dirs, center, cc, cfg)
                info.update(
                    r_knn=r_knn.tolist(),
                    r_cap=[None if not np.isfinite(x) else float(x) for x in r_cap],
                )
        cams = [_look(center, dirs[i], radii[i], up_v, intr, f"fib_{i:02d}") for i in range(n)]
    candidates = [
        Anchor(
            cams[i],
            dirs[i],
            float(ranking.score[i]),
            bool(unsupported[i]),
            "fibonacci",
            i,
            float(radii[i]),
        )
        for i in range(n)
    ]
    ranked = [candidates[i] for i in ranking.order]
    if forward_facing and not camera_free:
        anchors = [
            training_anchor(cameras, i, center) for i in _spread_training(cameras, cfg.top_k)
        ]
        if all_views:
            anchors += ranked
    elif all_views:
        anchors = ranked
    else:
        anchors = [a for a in ranked if not a.unsupported][: cfg.top_k]
    return AnchorPlan(
        anchors,
        candidates,
        ranking,
        center,
        up_v,
        frame,
        forward_facing,
        camera_free,
        kind,
        est,
        info,
        layout,
        intr,
    )


def plan_scene_anchors(
    scene: Scene,
    cameras: list[Camera] | None,
    *,
    kind: SceneKind = SceneKind.GS2D,
    config: ViewConfig | None = None,
    all_views: bool = False,
    up: np.ndarray | None = None,
) -> AnchorPlan:
    """:func:`plan_anchors` of a scene: with training cameras the paper's plan around
    :func:`scene_frame`; without them the up is estimated from the scene (or ``up`` /
    ``config.up``) and the anchors are framed on its robust foreground."""
    cfg = config or ViewConfig()
    fr = scene_frame(scene)
    layout = None if cameras else scene_layout(scene, cfg, up)
    return plan_anchors(
        fr.center,
        fr.radius,
        cameras,
        kind=kind,
        config=cfg,
        all_views=all_views,
        up=up,
        layout=layout,
    )

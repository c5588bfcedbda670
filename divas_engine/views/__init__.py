"""View selection and view generation (paper Sec. 3.2–3.3, App. C).

* :func:`plan_anchors` — anchor views: Fibonacci candidates (eq:fib) ranked by
  alg:view_ranking, per-direction 2DGS radius (eq:gs-radius) or the NeRF global
  radius, training-camera anchors for forward-facing captures, camera-free fallback.
* :func:`estimate_up` — scene up and capture type from the training cameras.
* :func:`plan_scene_anchors` / :func:`estimate_scene_up` / :func:`framed_camera` —
  camera-free captures: up from a ground plane or the capture convention, anchors
  framed on the robust foreground (not in the paper).
* :class:`GsCentroidPlanner` — 2DGS centroid views (alg:centroid-gs).
* :func:`nerf_centroid_view` — NeRF centroid views (alg:centroid_view).
* :class:`ViewConfig` — every constant, with its paper symbol.
"""

from .anchors import (
    Anchor,
    AnchorPlan,
    gs_anchor_radii,
    plan_anchors,
    plan_scene_anchors,
    representative_camera,
    scene_frame,
    scene_layout,
    training_anchor,
)
from .centroid_common import CentroidView, ProbeRecord, build_pose, click_point
from .centroid_gs import GsCentroidPlanner, central_patch, occluded_fraction
from .centroid_nerf import nerf_centroid_view
from .config import ViewConfig
from .fibonacci import fibonacci_sphere, up_frame
from .framing import SceneLayout, framed_camera, view_fill
from .ground import GroundPlane, ground_candidates, scene_points
from .ranking import Ranking, rank_directions
from .up_direction import SceneUp, UpEstimate, UpSource, estimate_scene_up, estimate_up

__all__ = [
    "Anchor",
    "AnchorPlan",
    "plan_anchors",
    "plan_scene_anchors",
    "scene_layout",
    "SceneLayout",
    "framed_camera",
    "view_fill",
    "GroundPlane",
    "ground_candidates",
    "scene_points",
    "SceneUp",
    "UpSource",
    "estimate_scene_up",
    "training_anchor",
    "gs_anchor_radii",
    "representative_camera",
    "scene_frame",
    "CentroidView",
    "ProbeRecord",
    "build_pose",
    "click_point",
    "GsCentroidPlanner",
    "central_patch",
    "occluded_fraction",
    "nerf_centroid_view",
    "ViewConfig",
    "fibonacci_sphere",
    "up_frame",
    "Ranking",
    "rank_directions",
    "UpEstimate",
    "estimate_up",
]

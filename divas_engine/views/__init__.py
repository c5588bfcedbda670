"""View selection and view generation (paper Sec. 3.2–3.3, App. C).

* :func:`plan_anchors` — anchor views: Fibonacci candidates (eq:fib) ranked by
  alg:view_ranking, per-direction 2DGS radius (eq:gs-radius) or the NeRF global
  radius, training-camera anchors for forward-facing captures, camera-free fallback.
* :func:`estimate_up` — scene up and capture type from the training cameras.
* :class:`GsCentroidPlanner` — 2DGS centroid views (alg:centroid-gs).
* :func:`nerf_centroid_view` — NeRF centroid views (alg:centroid_view).
* :class:`ViewConfig` — every constant, with its paper symbol.
"""

from .anchors import (
    Anchor,
    AnchorPlan,
    gs_anchor_radii,
    plan_anchors,
    representative_camera,
    scene_frame,
    training_anchor,
)
from .centroid_common import CentroidView, ProbeRecord, build_pose, click_point
from .centroid_gs import GsCentroidPlanner, central_patch, occluded_fraction
from .centroid_nerf import nerf_centroid_view
from .config import ViewConfig
from .fibonacci import fibonacci_sphere, up_frame
from .ranking import Ranking, rank_directions
from .up_direction import UpEstimate, estimate_up

__all__ = [
    "Anchor",
    "AnchorPlan",
    "plan_anchors",
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

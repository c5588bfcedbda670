"""What a segmenter is handed: the scene once (:class:`SceneBinding`), then each view it
segments (:class:`ViewContext`) — so it never calls its session back.

SAM and the classic segmenter read only a view's image and depth; the scene-aware
:mod:`.graph3d` also reads the scene (the binding) and the view's camera and the 3D clicks
of the view's object (the context); the evaluation oracle reads the view's ground truth.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..scene import Scene

__all__ = ["ObjectClicks", "SceneBinding", "ViewContext"]


@dataclass(frozen=True, eq=False)
class ObjectClicks:
    """The 3D clicks of one object so far (every anchor).

    Attributes:
        points: ``[K,3]`` back-projected click points (world units).
        positive: ``[K]`` bool, True for a positive click.
    """

    points: np.ndarray
    positive: np.ndarray

    @staticmethod
    def empty() -> ObjectClicks:
        return ObjectClicks(np.zeros((0, 3)), np.zeros(0, bool))


@dataclass(frozen=True, eq=False)
class ViewContext:
    """One view as its session hands it to a segmenter
    (:meth:`~.base.Segmenter.segment_view`).

    Attributes:
        id: the view's key (a session never reuses one for another image): the
            segmenter's per-view cache key.
        rgb: ``[H,W,3]`` the view's render; depth: ``[H,W]`` its planar depth
            ``D_ref`` (NOTES "Depth tuple"), or None.
        camera: the view's camera (the image's size), or None where the caller has none.
        clicks: the 3D clicks of the view's object on every anchor.
        truth: evaluation only — ``[H,W]`` ground-truth label coverage of the view in
            [0, 1], given when the segmenter asks for it
            (:attr:`~.base.Segmenter.wants_ground_truth`) and the session has ground truth.
    """

    id: Hashable
    rgb: np.ndarray
    depth: np.ndarray | None = None
    camera: Camera | None = None
    clicks: ObjectClicks = field(default_factory=ObjectClicks.empty)
    truth: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class SceneBinding:
    """The scene a session hands a scene-aware segmenter once
    (:meth:`~.base.Segmenter.bind_scene`).

    Attributes:
        scene: the session's scene (surfels or a density grid).
        render_values: ``(camera, values) -> [H,W] or [H,W,C]`` composite of
            per-primitive values (:meth:`~divas_engine.render.Renderer.render_values`).
        up: the scene up the session planned with (training cameras or estimated), or
            None.
        render_sparse: ``(camera, rows, values [K,C]) -> [H,W,C]``: ``render_values`` of
            values that are 0 off the primitives ``rows`` (sorted), computed with only
            the primitives that can blend before them
            (:meth:`~divas_engine.render.SurfelRenderer.render_values_sparse`), or None.
            It may take ``threads=`` (CPU launch threads) and run beside the session's
            other renders (the session's binding: on the CPU).
    """

    scene: Scene
    render_values: Callable[[Camera, np.ndarray], np.ndarray] | None = None
    up: Callable[[], np.ndarray | None] | None = None
    render_sparse: Callable[..., np.ndarray] | None = None

"""Segmenters that see the scene, not only the image (issue 16; not in the paper).

SAM and the oracle segment the rendered image of a centroid view. A *scene-aware*
segmenter also reads the scene's own primitives (positions, normals, colours,
opacities) and segments them in 3D, then renders that one 3D region into each view
as the view's mask — so every view sees the same region and the preview predicts the
fused result. It keeps SAM's contract (:class:`~.base.Segmenter`: 3 masks, 3 scores)
so fusion and mapping are unchanged.

The session binds it once (:meth:`SceneAwareSegmenter.bind_scene`) with a
:class:`SceneBinding`: the scene, how to render per-primitive values into a camera
(with the session's own renderer and render lock), the camera of a view id, and the
3D clicks of the object a view belongs to. SAM and the oracle never see a binding.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..scene import Scene
from .base import Segmenter

__all__ = ["SceneBinding", "SceneAwareSegmenter", "ObjectClicks"]


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
class SceneBinding:
    """What a scene-aware segmenter gets from the session that owns it.

    Attributes:
        scene: the session's scene (surfels or a density grid).
        render_values: ``(camera, values) -> [H,W] or [H,W,C]`` composite of
            per-primitive values (:meth:`~divas_engine.render.Renderer.render_values`).
        camera_of: the camera of a view id passed to ``segment`` / ``set_image``.
        clicks_of: the :class:`ObjectClicks` of the object a view id belongs to (None:
            only the view's own prompts are used).
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
    render_values: Callable[[Camera, np.ndarray], np.ndarray]
    camera_of: Callable[[Hashable], Camera]
    clicks_of: Callable[[Hashable], ObjectClicks] | None = None
    up: Callable[[], np.ndarray | None] | None = None
    render_sparse: Callable[..., np.ndarray] | None = None


class SceneAwareSegmenter(Segmenter):
    """A :class:`~.base.Segmenter` that needs a :class:`SceneBinding` before use.

    The session calls :meth:`bind_scene` once when it opens; callers without a session
    (benchmarks, tests) build the binding themselves.
    """

    binding: SceneBinding | None = None

    def bind_scene(self, binding: SceneBinding) -> None:
        """Attach the scene (once per session; a new binding drops every cached view)."""
        with self._lock:
            self.binding = binding
            self.clear_cache()
            self._on_bind(binding)

    @abstractmethod
    def _on_bind(self, binding: SceneBinding) -> None:
        """Per-scene preparation (features of the primitives, support planes …)."""

    def warm_up(self) -> None:  # noqa: B027 - optional hook
        """Build the per-scene state the first prompt would build (the session calls it
        in its background warm-up, after the fusion state, issue 20); the default does
        nothing. A failure is left for the first prompt to raise."""

"""Segmenters that see the scene, not only the image (not in the paper).

SAM and the oracle segment the rendered image of a centroid view. A *scene-aware*
segmenter also reads the scene's own primitives (positions, normals, colours,
opacities) and segments them in 3D, then renders that one 3D region into each view
as the view's mask — so every view sees the same region and the preview predicts the
fused result. It keeps SAM's contract (:class:`~.base.Segmenter`: 3 masks, 3 scores)
so fusion and mapping are unchanged.

The session binds it once (:meth:`~.base.Segmenter.bind_scene`) with a
:class:`~.context.SceneBinding` (the scene, and how to render per-primitive values into a
camera with the session's own renderer), then hands it each view as a
:class:`~.context.ViewContext` (camera, render, the object's 3D clicks).
"""

from __future__ import annotations

from abc import abstractmethod

from .base import Segmenter
from .context import ObjectClicks, SceneBinding

__all__ = ["SceneBinding", "SceneAwareSegmenter", "ObjectClicks"]


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

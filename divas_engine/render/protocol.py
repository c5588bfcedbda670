"""What the rest of the engine may ask of a renderer (paper Sec. 3.1: only the
rendering adapter differs between NeRF and 2DGS)."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from .buffers import RenderBuffers
from .config import RenderConfig

__all__ = ["Renderer"]


@runtime_checkable
class Renderer(Protocol):
    """A scene resident on one Warp device that renders views.

    Attributes:
        device: the Warp device the scene lives on (chosen once, at construction).
        config: the :class:`RenderConfig` in use.
        kind: :class:`~divas_engine.kinds.SceneKind` ``GS2D`` or ``NERF``.
    """

    device: Any
    config: RenderConfig
    kind: SceneKind

    def render(self, camera: Camera, scale: float = 1.0) -> RenderBuffers:
        """RGB and depth tuple of ``camera`` (resized by ``scale``)."""
        ...

    def render_values(self, camera: Camera, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Composite per-primitive ``values`` with the render's own weights.

        ``values``: 2DGS ``[N]`` or ``[N, C]`` per surfel; NeRF ``[D,H,W]`` or
        ``[D,H,W,C]`` per voxel (trilinear). Returns ``[H,W]`` or ``[H,W,C]``
        float32 ``Σ_k w_k v_k`` (no background): a constant 1 gives ``alpha``.
        Used for overlays and evaluation masks (NOTES "Evaluation").
        """
        ...

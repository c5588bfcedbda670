"""What the rest of the engine may ask of a renderer (paper Sec. 3.1: only the
rendering adapter differs between NeRF and 2DGS).

:class:`Renderer` declares the two renders every renderer has and the optional
abilities a session uses when a renderer has them, each with a no-op default that a
renderer overrides (the surfel rasterizer overrides all of them; the NeRF ray-marcher
none). Callers call the hooks; they never probe for them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from .buffers import RenderBuffers
from .config import RenderConfig

__all__ = ["Renderer"]


class Renderer(ABC):
    """A scene resident on one Warp device that renders views.

    Attributes:
        device: the Warp device the scene lives on (chosen once, at construction).
        config: the :class:`RenderConfig` in use.
        kind: :class:`~divas_engine.kinds.SceneKind` ``GS2D`` or ``NERF``.
        scratch_sparse: sparse value renders keep their working arrays between calls
            (a renderer without sparse renders ignores it).
    """

    device: Any
    config: RenderConfig
    kind: SceneKind
    scratch_sparse: bool = False

    @abstractmethod
    def render(self, camera: Camera, scale: float = 1.0, *, attached: bool = True) -> RenderBuffers:
        """RGB and depth tuple of ``camera`` (resized by ``scale``); ``attached`` False:
        without the channels of :meth:`attach_values` (an image nobody segments)."""

    @abstractmethod
    def render_values(self, camera: Camera, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Composite per-primitive ``values`` with the render's own weights.

        ``values``: 2DGS ``[N]`` or ``[N, C]`` per surfel; NeRF ``[D,H,W]`` or
        ``[D,H,W,C]`` per voxel (trilinear). Returns ``[H,W]`` or ``[H,W,C]``
        float32 ``Σ_k w_k v_k`` (no background): a constant 1 gives ``alpha``.
        Used for overlays and evaluation masks (NOTES "Evaluation").
        """

    # -- optional abilities (no-op defaults) -------------------------------------------
    def render_depth(
        self, camera: Camera, scale: float = 1.0, window: tuple[int, int, int, int] | None = None
    ) -> RenderBuffers:
        """The depth tuple of ``camera``, at least inside ``window`` (``(x0, y0, x1, y1)``
        pixels): the centroid planner's probes. The default is the whole render."""
        return self.render(camera, scale)

    def attach_values(self, values: np.ndarray | None) -> None:  # noqa: B027 - optional hook
        """Values every later :meth:`render` composites in its own blend, so that a
        :meth:`render_values` of them at a camera just rendered needs no second blend
        (the same image); None detaches. The default composites nothing ahead."""

    def release(self, camera: Camera) -> bool:
        """Drop what is kept for ``camera`` (a view done with); whether anything was
        dropped. The default keeps nothing."""
        return False

    @property
    def renders_sparse(self) -> bool:
        """Whether :meth:`render_values_sparse` is offered (default: no)."""
        return False

    @property
    def sparse_renders_concurrent(self) -> bool:
        """Whether :meth:`render_values_sparse` may run while another render runs."""
        return False

    def render_values_sparse(
        self, camera: Camera, rows: np.ndarray, values: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """:meth:`render_values` of values that are 0 off the primitives ``rows``, at the
        cost of the primitives that can blend before them (where :attr:`renders_sparse`)."""
        raise NotImplementedError(f"{type(self).__name__} has no sparse value render")

    def sparse_index(self) -> Any:
        """Build (once) what sparse renders need; the default needs nothing (None)."""
        return None

    @property
    def surfel_buffers(self) -> Any:
        """The scene's device surfel buffers, for passes that share this renderer's kept
        binnings (None: not a surfel renderer)."""
        return None

    def kept_binning(self, camera: Camera) -> Any:
        """The kept binning of ``camera`` as rendered, or None (the default keeps none)."""
        return None

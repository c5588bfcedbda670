"""The per-view output of every renderer (paper Sec. 3.1, NOTES "Depth tuple")."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind

__all__ = ["RenderBuffers", "DEPTH_CHANNELS", "NPZ_CHANNELS"]

#: Depth channels, in the order the CLI writes them.
DEPTH_CHANNELS = ("D_min", "D_ref", "D_max", "D_mw", "D_exp", "D_med")
#: Every array channel, under its NOTES name.
NPZ_CHANNELS = ("rgb", "alpha") + DEPTH_CHANNELS + ("N_samp",)


@dataclass(eq=False)
class RenderBuffers:
    """RGB and the depth tuple ``(D_min, D_ref, D_max, D_mw, N_samp)`` of one view.

    All depths are *planar* camera depth (camera z, world units); ``0`` marks an
    invalid pixel (no such element). Per pixel, front to back, ``w_k = α_k T_k``:

    Attributes:
        rgb: ``[H,W,3]`` float32 composited colour (background included).
        alpha: ``[H,W]`` float32 accumulated opacity ``1 − T``.
        D_min: ``[H,W]`` depth of the first element with ``w_k ≥ τ_sig``.
        D_ref: ``[H,W]`` the backbone's surface estimate: ``D_med`` (2DGS) or ``D_exp`` (NeRF).
        D_max: ``[H,W]`` depth at which ``1 − T`` first reaches ``τ_cw``, else the last
            contributing element.
        D_mw: ``[H,W]`` depth of the largest ``w_k``.
        D_exp: ``[H,W]`` expected depth ``Σ w z / Σ w``.
        D_med: ``[H,W]`` depth at which ``1 − T`` first reaches 0.5 (computed by both renderers).
        N_samp: ``[H,W]`` int32 elements with ``α ≥ 1/255`` traversed up to and including
            the ``D_med`` primitive (2DGS) or the ``D_max`` sample (NeRF); no anchor → all.
        camera: the camera actually rendered (after ``scale``).
        kind: :class:`~divas_engine.kinds.SceneKind` ``GS2D`` or ``NERF``.
        stats: renderer counters (visible primitives, pairs, …).
    """

    rgb: np.ndarray
    alpha: np.ndarray
    D_min: np.ndarray
    D_ref: np.ndarray
    D_max: np.ndarray
    D_mw: np.ndarray
    D_exp: np.ndarray
    D_med: np.ndarray
    N_samp: np.ndarray
    camera: Camera
    kind: SceneKind = SceneKind.GS2D
    stats: dict | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.alpha.shape

    def as_dict(self) -> dict[str, np.ndarray]:
        """Every array channel under its NOTES name (``rgb, alpha, D_min, …, N_samp``)."""
        return {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)
        }

"""Session backend of density grids (the NeRF path of the paper).

Occupancy from the density (App. B, preset ``llff`` / ``mip360``), the NeRF centroid
view (Sec. 3.3), the depth weight eq:nerf-depthweight, asynchronous SAM with group
fusion (Sec. 3.4) and the segmented voxels as the selection; exports are masked grids.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...camera import Camera
from ...errors import DivasInputError
from ...kinds import SceneKind
from ...output_paths import save_npy_atomic
from ...render.buffers import RenderBuffers
from ...scene import DensityGrid, Scene
from ...segment.depth_weighting import DepthBand, apply_nerf_depth_weight
from ...views.centroid_common import CentroidView
from .base import SessionBackend
from .registry import register_backend

if TYPE_CHECKING:
    from ...fusion import FusionResult
    from ..config import SessionConfig
    from ..records import SessionView

__all__ = ["DensityGridBackend"]


@register_backend
class DensityGridBackend(SessionBackend):
    """Density grids (NeRF).

    Attributes:
        preset: ``SessionConfig.nerf_preset``, else ``"llff"`` forward-facing and
            ``"mip360"`` otherwise; nerf_config: its :class:`~divas_engine.fusion.NerfFusionConfig`.
    """

    scene_type = DensityGrid
    kind = SceneKind.NERF

    def __init__(
        self, scene: Scene, config: SessionConfig, *, forward_facing: bool, device, renderer
    ) -> None:
        from ...fusion import NerfFusion, build_nerf_occupancy, nerf_preset

        super().__init__(
            scene, config, forward_facing=forward_facing, device=device, renderer=renderer
        )
        self.preset = config.nerf_preset or ("llff" if self.forward_facing else "mip360")
        self.nerf_config = nerf_preset(self.preset)
        self.grid = build_nerf_occupancy(scene, self.nerf_config, device)
        self.fusion = NerfFusion(self.grid, self.nerf_config, device)

    @staticmethod
    def fingerprint_array(scene: Scene) -> np.ndarray:
        return scene.density

    @property
    def selection_shape(self) -> tuple[int, ...]:
        return self.scene.density.shape

    def click_depth(self, buffers: RenderBuffers) -> np.ndarray:
        return buffers.D_mw

    def centroid_view(
        self,
        camera: Camera,
        xy: tuple[float, float],
        buffers: RenderBuffers,
        name: str,
        on_camera: Callable[[Camera], None] | None = None,
    ) -> CentroidView:
        from ...views import nerf_centroid_view

        cv = nerf_centroid_view(
            camera,
            xy,
            buffers,
            zoom=self.config.nerf_zoom,
            forward_facing=self.forward_facing,
            config=self.config.view,
            name=name,
        )
        if on_camera is not None:  # the session renders the view next
            on_camera(cv.camera)
        return cv

    def click_patch(self, point: np.ndarray, radius: float, sigmas: float) -> np.ndarray:
        from ..corrections import grid_patch

        return grid_patch(self.scene, point, radius, sigmas)

    def depth_weight(
        self, mask: np.ndarray, buffers: RenderBuffers, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, DepthBand | None]:
        return apply_nerf_depth_weight(mask, buffers.D_ref, config=self.config.nerf_weight), None

    @property
    def asynchronous(self) -> bool:
        return bool(self.config.nerf_async)

    def selection(self, fused: FusionResult, live: Sequence[SessionView]) -> np.ndarray:
        return self.grid.to_dense(fused.segmented.astype(bool), False)

    def object_suffix(self) -> str:
        return ".npz"

    def write_label_set(self, labels: np.ndarray, out_dir: Path) -> Path:
        return save_npy_atomic(out_dir / "labels.npy", labels)

    def write_labelled(self, labels: np.ndarray, path: str | PathLike) -> Path:
        raise DivasInputError(path, "labelled PLY needs a surfel scene (NeRF: labels.npy)")

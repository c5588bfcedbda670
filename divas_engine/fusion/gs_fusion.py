"""2DGS surfel-voxel fusion, incremental and exactly undoable (paper Sec. 3.5,
alg:gs-fusion, alg:gs-thin, App. B; kernel in ``divas_kernels.fusion_gs``).

Usage::

    grid = build_occupancy(scene, GridConfig(), device)
    fusion = GsFusion(grid, GsFusionConfig())
    vid = fusion.add_view(FusionView(camera, mask, d_min, d_med, d_max, n_samp, d_cam))
    fusion.remove_view(vid)            # exact undo
    res = fusion.result()              # P, V_seg, view bitmask per active voxel

Accumulation is int64 fixed point with per-view sparse records for undo (``state.py``); a
view's bitmask bit is its slot (≤ 64 live). The 13 decisions on points the paper leaves open
(sampling, gates, footprint, fallbacks, the ordered depth-weight segment) are listed in
docs/design-notes.md.
"""

from __future__ import annotations

from divas_kernels import GsParams, ViewData, gs_fuse_view, resolve_device

from .config import GsFusionConfig
from .occupancy import OccupancyGrid
from .state import FusionResult, IncrementalFusion
from .views import FusionView

__all__ = ["GsFusion", "gs_params", "fuse_views_gs"]


def gs_params(config: GsFusionConfig, h_v: float) -> GsParams:
    """Device constants of the 2DGS kernel."""
    p = GsParams()
    p.h = float(h_v)
    p.gamma, p.beta, p.gamma_st = float(config.gamma), float(config.beta), float(config.gamma_st)
    p.tau_thin, p.behind_margin = float(config.tau_thin), float(config.behind_margin)
    p.rho_cover, p.rho_occ, p.n_abs = (
        float(config.rho_cover),
        float(config.rho_occ),
        int(config.n_abs),
    )
    p.dist_gate, p.rho_thin, p.alpha1 = (
        float(config.dist_gate),
        float(config.rho_thin),
        float(config.alpha1),
    )
    p.m_thick, p.m_pos, p.eps = float(config.m_thick), float(config.m_pos), float(config.eps)
    p.early_out = 1 if config.early_out else 0
    return p


class GsFusion(IncrementalFusion):
    """Incremental 2DGS fusion over the active voxels of an :class:`OccupancyGrid`."""

    def __init__(
        self, grid: OccupancyGrid, config: GsFusionConfig = GsFusionConfig(), device=None
    ) -> None:
        device = resolve_device(device) if device is not None else grid.device
        if device != grid.device:
            raise ValueError(f"GsFusion: grid lives on {grid.device}, asked for {device}")
        super().__init__(
            len(grid),
            max_views=config.max_views,
            eps=config.eps,
            tau_cons=config.tau_cons,
            mask_pos=config.m_pos,
            k_dg=config.k_dg,
            device=device,
        )
        self.grid = grid
        self.config = config
        self._geom = grid.geometry.device_geom()
        self._params = gs_params(config, grid.geometry.voxel_size)

    def upload(self, view: FusionView) -> ViewData:
        if not view.d_cam > 0:
            raise ValueError(
                f"2DGS fusion: view {view.name!r} needs d_cam > 0 (eq:seethrough; "
                f"NOTES: orbit radius or distance to the look-at point)"
            )
        return super().upload(view)

    def _launch(self, vd: ViewData) -> None:
        gs_fuse_view(
            self.grid.codes,
            self.grid.density,
            self._geom,
            vd,
            self._params,
            self._num,
            self._den,
            self._kind,
            device=self.device,
        )

    def contributions(self, view: FusionView) -> tuple:
        """Dense ``(num, den, kind)`` host arrays of one view, without fusing it."""
        self._launch(self.upload(view))
        return self._num.numpy().copy(), self._den.numpy().copy(), self._kind.numpy().copy()


def fuse_views_gs(
    grid: OccupancyGrid, views: list[FusionView], config: GsFusionConfig = GsFusionConfig()
) -> FusionResult:
    """Full (non-incremental) fuse of ``views``; view ``i`` gets bit ``i``."""
    f = GsFusion(grid, config)
    for i, v in enumerate(views):
        f.add_view(v, i)
    return f.result()

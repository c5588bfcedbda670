"""NeRF fusion, incremental and exactly undoable (paper App. A, alg:nerf-fusion,
alg:nerf-thin; kernel in ``divas_kernels.fusion_nerf``).

Usage::

    cfg = nerf_preset("llff")
    occ = build_nerf_occupancy(density_grid, cfg, device)
    fusion = NerfFusion(occ, cfg)
    vid = fusion.add_view(FusionView(camera, mask, d_min, d_exp, d_max, n_samp))
    P = occ.to_dense(fusion.result().P)   # [D,H,W] probability grid

The NeRF path has no view-coverage bitmask (eq:vmask has no NeRF analogue), so the
number of live views is unbounded. See ``divas_kernels.fusion_nerf`` for the decisions on
points the paper leaves open.
"""

from __future__ import annotations

from divas_kernels import NerfParams, ViewData, nerf_fuse_view, resolve_device

from .config import NerfFusionConfig
from .nerf_occupancy import NerfOccupancy
from .state import FusionResult, IncrementalFusion
from .views import FusionView

__all__ = ["NerfFusion", "nerf_params", "fuse_views_nerf"]


def nerf_params(config: NerfFusionConfig) -> NerfParams:
    p = NerfParams()
    p.gamma, p.beta, p.b_max = float(config.gamma), float(config.beta), float(config.b_max)
    p.lambda_range, p.rho_thin = float(config.lambda_range), float(config.rho_thin)
    p.rho_cover, p.tau_thin, p.alpha1 = (
        float(config.rho_cover),
        float(config.tau_thin),
        float(config.alpha1),
    )
    p.m_thick, p.m_thin_gate, p.m_pos = (
        float(config.m_thick),
        float(config.m_thin_gate),
        float(config.m_pos),
    )
    p.eps = float(config.eps)
    p.early_out = 1 if config.early_out else 0
    return p


class NerfFusion(IncrementalFusion):
    """Incremental NeRF fusion over the active cells of a :class:`NerfOccupancy`."""

    def __init__(
        self, occ: NerfOccupancy, config: NerfFusionConfig | None = None, device=None
    ) -> None:
        config = occ.config if config is None else config
        device = resolve_device(device) if device is not None else occ.device
        if device != occ.device:
            raise ValueError(f"NerfFusion: occupancy lives on {occ.device}, asked for {device}")
        super().__init__(
            len(occ),
            max_views=None,
            eps=config.eps,
            tau_cons=config.tau_cons,
            mask_pos=config.m_pos,
            k_dg=config.k_dg,
            device=device,
        )
        self.occ = occ
        self.config = config
        self._geom = occ.device_geom()
        self._params = nerf_params(config)

    def _launch(self, vd: ViewData) -> None:
        nerf_fuse_view(
            self.occ.index,
            self.occ.density,
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


def fuse_views_nerf(
    occ: NerfOccupancy, views: list[FusionView], config: NerfFusionConfig | None = None
) -> FusionResult:
    """Full (non-incremental) fuse of ``views``."""
    f = NerfFusion(occ, config)
    for v in views:
        f.add_view(v)
    return f.result()

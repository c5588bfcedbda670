"""2DGS surfel-voxel fusion, incremental and exactly undoable (paper Sec. 3.5,
alg:gs-fusion, alg:gs-thin, App. B; kernel in ``divas_kernels.fusion_gs``).

Usage::

    grid = build_occupancy(scene, GridConfig(), device)
    fusion = GsFusion(grid, GsFusionConfig())
    vid = fusion.add_view(FusionView(camera, mask, d_min, d_med, d_max, n_samp, d_cam))
    fusion.remove_view(vid)            # exact undo
    res = fusion.result()              # P, V_seg, view bitmask per active voxel

Decisions on points the paper leaves open (see also the kernel docstring):

1. Sampling: nearest pixel ``⌊u⌋, ⌊v⌋`` of the projected centre; in-frame means
   ``0 ≤ u < W ∧ 0 ≤ v < H`` and ``x_d > ε``.
2. eq:planar-to-ray uses the ray through the centre of that pixel (the ray its
   depths were rendered along); the spatial gate therefore includes the voxel's
   lateral offset from that ray.
3. Depth gates (eq:asym-gate, eq:behind-gate, thin gate) compare planar ``x_d``
   with planar buffers; spatial gate and depth weight use ray depths.
4. The footprint B is the pixel box ``⌊u_min⌋…⌊u_max⌋ × ⌊v_min⌋…⌊v_max⌋`` of the 8
   projected corners clipped to the image; A_B = its pixel count (|B|, main text);
   n̄, σ_n are the mean and population std of N_samp over B (pixels without a
   surface included, N_samp = 0 there). A corner at z ≤ ε skips the view.
5. layered / see-through / trusted are computed for every in-frame voxel; a centre
   pixel without surface (D_med < ε) cannot vote thick and passes the behind gate.
6. Missing D_min or D_max (< ε) at a pixel falls back to D_med.
7. The thin per-pixel gate is one-sided (against D_min) iff that pixel is layered,
   two-sided against D_med otherwise — alg:gs-thin has no see-through input, and a
   one-sided gate on see-through background would let the background dilute
   p_covered; unprojection uses D_min iff the pixel is layered.
8. ⌈ρ_occ A_B⌉ is taken with a 1e-4 slack (0.1·30 → 3, not 4).
9. π_dg (App. D, NOTES): relative central differences of ½(D_min+D_max),
   edge-replicated at the image border; a surface-less pixel has π_dg = 0 and reads
   as depth 0 when it is a neighbour.
10. A thin vote needs t > 0 besides t ≥ τ_thin (matters only if τ_thin ≤ 0).
11. Exact early-out: a thin sweep is skipped when the footprint holds fewer
    mask-positive pixels than ρ_cover·n_min (the acceptance would need at least as
    many); a test checks identical output with and without it.
12. Accumulation in int64 fixed point, per-view sparse records for undo
    (``state.py``); the bitmask bit of a view is its slot, ≤ max_views (64) live.
13. eq:gs-depthweight runs on the ordered segment ``[d_min, max(d_max, d_ref)]``: the
    depth tuple is not monotone on 2DGS (per-primitive hits blended in centre-depth
    order), and with D_max a hair before D_min the literal half-width collapses to ε
    and the weight of an accepted thick vote to 0 (kernel docstring).
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

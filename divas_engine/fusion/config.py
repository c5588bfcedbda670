"""Configuration of the occupancy grids and fusion kernels (paper Sec. 3.5, App. A/B,
tab:gs-hyperparams, tab:kernel_hyperparams; NOTES "Occupancy", "Fusion constants").

Every constant of the kernels lives here with its paper symbol; no literal is buried
in a kernel.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["GridConfig", "GsFusionConfig", "NerfFusionConfig", "NERF_PRESETS", "nerf_preset"]


@dataclass(frozen=True)
class GridConfig:
    """2DGS occupancy grid (eq:scene-norm, eq:voxel-size, tab:gs-hyperparams).

    Attributes:
        alpha_v: α_v, voxel-size scale on the median surfel scale s̄ (3σ rule).
        beta_v: β_v, voxel-size scale on r_scene / g_0.
        g0: g_0, reference resolution of the scene-scale term.
        g_max: g_max, resolution cap — 512 forward-facing (LLFF), 1024 otherwise.
        tau_tf: τ_TF, summed-opacity floor of an active voxel (also the thin-path
            density floor ρ_thin of 2DGS, App. G).
        pad: AABB safety pad, ``b = pad · r_fg`` (NOTES: the paper's ceil() is dropped).
        percentile: percentile of the radial distance defining r_fg (eq:scene-norm).
    """

    alpha_v: float = 3.0
    beta_v: float = 1.0
    g0: int = 256
    g_max: int = 1024
    tau_tf: float = 0.5
    pad: float = 1.05
    percentile: float = 99.0

    @classmethod
    def forward_facing(cls, **kw) -> GridConfig:
        """LLFF-style captures: ``g_max = 512``."""
        return cls(g_max=512, **kw)

    def __post_init__(self) -> None:
        g = int(self.g_max)
        if g < 1 or g & (g - 1) or g > (1 << 21):
            raise ValueError(f"GridConfig.g_max={self.g_max} must be a power of two ≤ 2^21")
        for k in ("alpha_v", "beta_v", "pad"):
            if not getattr(self, k) > 0:
                raise ValueError(f"GridConfig.{k} must be positive")
        if self.g0 < 1:
            raise ValueError("GridConfig.g0 must be ≥ 1")


@dataclass(frozen=True)
class GsFusionConfig:
    """2DGS fusion kernel constants (alg:gs-fusion, alg:gs-thin, tab:gs-hyperparams).

    Attributes:
        gamma: γ, base depth tolerance in units of h_v (eq:tightening).
        beta: β, inverted per-sample tightening strength (eq:tightening).
        b_max: b_max of the table; has no term in eq:tightening (NOTES) — unused.
        gamma_st: γ_ST, see-through gap as a multiple of d_cam (eq:seethrough).
        tau_thin: τ_thin, thin acceptance threshold (eq:compact-fusion).
        tau_cons: τ_cons, consensus threshold (eq:compact-fusion).
        behind_margin: behind-surface margin in h_v (eq:behind-gate, "2 h_v").
        rho_cover: ρ_cover, coverage threshold on n_{m∧d}/n_depth (eq:thin-tthin-gs).
        rho_occ: ρ_occ, fractional pixel floor of the footprint (eq:thin-nmin).
        n_abs: n_abs, absolute pixel floor (eq:thin-nmin).
        dist_gate: 3D distance gate in h_v (eq:thin-tthin-gs, "1.5 h_v").
        rho_thin: ρ_thin_thresh, thin-path density floor (App. G: 0.5 = τ_TF).
        alpha1: α₁, depth-weight falloff (eq:gs-depthweight; NOTES 1.0).
        k_dg: k of the depth-gradient factor π_dg (App. D; NOTES 400).
        m_thick: thick-path entry, ``m ≥ m_thick`` (NOTES 0.5).
        m_pos: thin mask-positive pixel, ``m > m_pos`` (NOTES 0.5).
        eps: ε — invalid depth ``D < ε``, denominator floor ``Z > ε``, half-width floor.
        max_views: bits of the view-coverage bitmask (eq:vmask; NOTES ≥ 64).
        early_out: skip thin sweeps whose footprint cannot pass (exact; NOTES).
    """

    gamma: float = 1.0
    beta: float = 0.05
    b_max: float = 0.5
    gamma_st: float = 1.5
    tau_thin: float = 0.6
    tau_cons: float = 0.5
    behind_margin: float = 2.0
    rho_cover: float = 0.5
    rho_occ: float = 0.1
    n_abs: int = 25
    dist_gate: float = 1.5
    rho_thin: float = 0.5
    alpha1: float = 1.0
    k_dg: float = 400.0
    m_thick: float = 0.5
    m_pos: float = 0.5
    eps: float = 1e-6
    max_views: int = 64
    early_out: bool = True

    def __post_init__(self) -> None:
        if self.max_views < 1:
            raise ValueError("GsFusionConfig.max_views must be ≥ 1")


@dataclass(frozen=True)
class NerfFusionConfig:
    """NeRF fusion kernel constants (alg:nerf-fusion, alg:nerf-thin, tab:kernel_hyperparams).

    Every entry of the paper's NeRF table, plus the constants its algorithms use.

    Attributes:
        gamma: γ, base tolerance multiplier (eq:depth_tol; thin: 2γ, eq:nerf-thindepth).
        beta: β, per-sample bonus (eq:depth_tol).
        b_max: b_max, cap on the bonus (eq:depth_tol).
        lambda_range: λ_range, depth-range factor of τ_spatial (eq:dist_tol).
        rho_thresh: ρ_thresh, density of a valid (active) voxel.
        rho_thin: ρ_thin_thresh, thin-path density floor.
        rho_cover: ρ_cover (thin_percent_cover), eq:nerf-thin.
        grid_resolution: occupancy/segmentation grid resolution per axis (128 / 256).
        tau_cw: τ_cw, cumulative-weight cutoff of D_max (used by the renderer; kept
            here so the preset is the whole table).
        tau_thin: τ_thin, thin acceptance (eq:compact-fusion).
        tau_cons: τ_cons, consensus threshold (eq:compact-fusion).
        alpha1: α₁, depth-weight falloff (eq:nerf-vote; NOTES 1.0).
        k_dg: k of π_dg (App. D; NOTES 400).
        m_thick: thick entry ``m ≥ 0.5``; m_thin_gate: thin eligibility ``m > 0.1``;
        m_pos: supportive pixel ``m > 0.5`` (eq:nerf-support).
        eps: ε (invalid depth, denominators, half-width floor).
        early_out: skip thin sweeps whose footprint holds no mask-positive pixel.
    """

    gamma: float
    beta: float
    b_max: float
    lambda_range: float
    rho_thresh: float
    rho_thin: float
    rho_cover: float
    grid_resolution: int
    tau_cw: float = 0.75
    tau_thin: float = 0.6
    tau_cons: float = 0.5
    alpha1: float = 1.0
    k_dg: float = 400.0
    m_thick: float = 0.5
    m_thin_gate: float = 0.1
    m_pos: float = 0.5
    eps: float = 1e-6
    early_out: bool = True

    def with_(self, **kw) -> NerfFusionConfig:
        return replace(self, **kw)


#: tab:kernel_hyperparams — LLFF (uniform sampling) and Mip-NeRF 360 (proposal sampling).
NERF_PRESETS: dict[str, NerfFusionConfig] = {
    "llff": NerfFusionConfig(
        gamma=4.0,
        beta=0.2,
        b_max=10.0,
        lambda_range=0.05,
        rho_thresh=10.0,
        rho_thin=50.0,
        rho_cover=0.20,
        grid_resolution=128,
    ),
    "mip360": NerfFusionConfig(
        gamma=0.5,
        beta=0.2,
        b_max=1.0,
        lambda_range=5.0,
        rho_thresh=5.0,
        rho_thin=30.0,
        rho_cover=0.30,
        grid_resolution=256,
    ),
}


def nerf_preset(name: str, **overrides) -> NerfFusionConfig:
    """The preset ``"llff"`` or ``"mip360"``, optionally with overrides."""
    try:
        cfg = NERF_PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown NeRF preset {name!r}; expected one of {sorted(NERF_PRESETS)}"
        ) from None
    return replace(cfg, **overrides) if overrides else cfg

"""Constants of the 2DGS voxel-to-surfel mapping (paper Sec. 3.6, tab:gs-hyperparams
"Voxel-to-surfel mapping", alg:vox2surfel)."""

from __future__ import annotations

from dataclasses import dataclass

from divas_kernels import render_defaults as RD

__all__ = ["MappingConfig"]


@dataclass(frozen=True)
class MappingConfig:
    """Voxel-to-surfel mapping constants; defaults are the paper's.

    Attributes:
        needle_percentile: τ_a = P_{needle_percentile}({a_i}_{i=1}^{M}) over *all* surfels
            of the scene (eq:needle; 99). NumPy's linear-interpolation percentile.
        aspect_eps: ε of eq:aspect, ``a_i = max(s)/(min(s) + ε)`` (not stated by the paper;
            only guards a zero scale).
        mask_threshold: τ_M, a pixel is foreground when ``M̃_s ≥ τ_M`` (eq:cov-atomics; 0.5).
        surfel_coverage: τ_κ, final cull ``κ_i ≥ τ_κ`` (eq:final-F; 0.5).
        box_sigma: half-extent of the enumerated box in tangent σ ("Tangent containment
            1σ"; alg:vox2surfel (ii)).
        accept_sigma: per-pixel acceptance radius: ``u² + v² ≤ accept_sigma²`` (the
            rasterizer's 3σ ellipse test, alg:vox2surfel (iv)).
        near: near plane (planar camera depth, world units; the renderer's default), or
            the view camera's own larger near (``Camera.clip_near``): a surfel is scored
            in a view only if its whole acceptance disc lies beyond it.
        needle_filter: apply Pass 2 (False: ``f² = f¹``; tab:ablation_needle_surfel).
        coverage_filter: apply Pass 3 (False: ``f = f²``; tab:ablation_needle_surfel).
        early_out: exact early-outs in Pass 3 (identical κ; see ``kernels/coverage.py``).
        threads: CPU launch threads (None: all usable cores; ignored on CUDA).
    """

    needle_percentile: float = 99.0
    aspect_eps: float = 1e-12
    mask_threshold: float = 0.5
    surfel_coverage: float = 0.5
    box_sigma: float = 1.0
    accept_sigma: float = 3.0
    near: float = RD.NEAR
    needle_filter: bool = True
    coverage_filter: bool = True
    early_out: bool = True
    threads: int | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.needle_percentile <= 100.0:
            raise ValueError(
                f"MappingConfig.needle_percentile={self.needle_percentile} outside [0, 100]"
            )
        for k in ("box_sigma", "accept_sigma", "near"):
            if not getattr(self, k) > 0:
                raise ValueError(f"MappingConfig.{k} must be positive")
        if not self.aspect_eps >= 0:
            raise ValueError("MappingConfig.aspect_eps must be ≥ 0")

"""Constants of the 2DGS voxel-to-surfel mapping (paper Sec. 3.6, tab:gs-hyperparams
"Voxel-to-surfel mapping", alg:vox2surfel)."""

from __future__ import annotations

from dataclasses import dataclass, field

from divas_kernels import render_defaults as RD

__all__ = ["MappingConfig", "CompletionConfig"]


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
        completion: the completion of 3DGS-derived scenes (beyond the paper,
            :class:`CompletionConfig`); ignored on 2DGS scenes.
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
    completion: CompletionConfig = field(default_factory=lambda: CompletionConfig())

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


@dataclass(frozen=True)
class CompletionConfig:
    """Completion of the selection on volumetric (3DGS-derived) scenes — beyond the paper
    (:mod:`divas_engine.mapping.completion`). Runs only on ``SceneKind.GS3D``
    scenes; 2DGS input keeps the paper's three passes exactly.

    Attributes:
        enabled: run the completion on 3DGS scenes (False: the paper's selection only;
            ``divas segment --no-completion``).
        mask_threshold: τ_M, a fused-mask pixel is positive when ``M̃ ≥ τ_M`` (0.5, as
            Pass 3 and the thick entry).
        gamma: background bias γ of the contribution test (FlashSplat's slackness on the
            L2-normalised ``(A₀, A₁)``): a Gaussian is contribution-positive when
            ``A₁ − A₀ > γ √(A₀² + A₁²)`` (0: the plain majority of its blending weight).
        min_weight: a Gaussian has contribution evidence when its blending weight summed
            over the fused views ``A₀ + A₁ ≥ min_weight`` (full-resolution pixels; 0.01:
            a hundredth of a fully weighted pixel); below it only the solid fill
            decides. Larger values leave the small and half-hidden Gaussians the masks
            do claim to the fill, which misses those outside filled voxels.
        min_visibility: τ_vis, a Gaussian is *seen* in a fused view when its blending
            weight there is at least τ_vis × its unoccluded footprint weight
            ``o · 2π s₁ s₂ |cos θ| f_x f_y / z²`` (its weight with transmittance 1);
            a contribution-positive Gaussian seen in no view (seen only through other
            surfaces) is added only when its centre lies within the solid depth behind
            a mask-positive surface (``depth_factor``) in ``fill_min_views`` views
            (deeper says nothing unless ``deep_is_inconsistent``) — as the fill's
            hidden voxels. 0.1 separates the two: Gaussians seen only through the
            object (a table behind a pot, T ≈ 0.002) have visibility ≲ 0.03, those the
            masks see ≳ 0.3. 0 turns the rule off.
        appearance_k: a contribution-positive Gaussian seen in no view that the depth
            rule above leaves out still joins when, among the ``appearance_k`` Gaussians
            of the neighbourhood nearest to it in 3D that some view *sees*, the one of
            closest colour (SH DC) is in the selection: the object's own inside seen
            through its front looks like the object, the support seen through the object
            like the support's seen part next to it (:mod:`divas_engine.mapping.appearance`).
            0 (the default) turns the rule off. It raises alpha fidelity and PSNR on the
            real captures but lowers image IoU on the synthetic scenes, hence off.
        neighbourhood_log2: the neighbourhood of the voxel selection is the set of coarse
            cells of ``2^k`` voxels per side holding a segmented (or filled) voxel,
            dilated by one cell: everything within ``2^k … 2^(k+1)`` voxels (1: 2–4 h_v).
            Contribution and fill additions are restricted to it, so floaters and
            surfaces away from the object stay out. 1, not 0: k = 0 gains op-IoU but
            loses the large Gaussians whose centres lie 2–4 voxels out (a ghost render).
        surface_margin: ``|z − D_med| ≤ surface_margin · h_v`` is "on the visible
            surface" of a view (2, the fusion's behind-gate margin, eq:behind-gate);
            further in front is a floater in front of the object.
        depth_factor: a voxel hidden behind a mask-positive surface supports the object
            only within ``depth_factor`` × the depth a solid of that silhouette can have
            there: the chord ``2 √(ρ(2R − ρ))`` of a ball of the mask's inscribed radius
            R at the pixel's distance ρ from the silhouette edge (pixels, × z / f) — a
            solid object is about as deep as it is wide; deeper is what lies behind it.
        deep_is_inconsistent: a voxel hidden behind a mask-positive surface deeper than
            that carves (True) or says nothing (False: it may still be the object seen
            obliquely; the other views decide; the default).
        fill_rounds: at most this many growth rounds of the solid fill (each grows the
            filled region by one neighbourhood, 2–4 voxels).
        fill_min_views: a voxel *hidden* behind mask-positive surfaces joins the fill
            only when at least this many fused views are consistent with it (2: the
            intersection of two visual cones is bounded in 3D, one cone alone is not);
            a voxel seen on the surface inside a mask needs one view. Views along one
            sight (a click's view and its wider views) count once
            (:mod:`.completion_sights`).
        centre_evidence: a Gaussian that is not contribution-positive and joins only
            because its centre voxel is segmented or filled must also pass the fill's
            test at its own centre: on or within the solid depth behind a mask-positive
            surface in some fused view, inconsistent in none. A voxel is ``h_v`` wide
            (0.072 scene units on the guitar capture, a stand tube's width) and its centre
            alone speaks for it: one view where that centre falls on a thin object's mask
            fills it, and the voxel then adds what else it holds — the guitar body's
            hidden interior behind the stand. The rule raises op-IoU slightly but lowers
            PSNR (the false Gaussians it drops rendered inside the silhouette), so it is
            off by default.
        drop_inconsistent: also drop Gaussians of the paper's selection whose blending
            weight over the fused views lies mostly outside the masks (the same test,
            the other way: not ``A₁ − A₀ > γ ‖A‖`` with evidence ``≥ drop_min_weight``;
            True).
        drop_min_weight: the evidence a drop needs (0.5 pixel: taking a Gaussian out of
            the paper's selection needs more than the trace of weight an addition near
            the selection may rest on — a surface Gaussian at the silhouette's edge
            has a little weight, mostly just outside the mask).
        sparse_gather: gather a view's records (contributions and voxel evidence)
            only for the Gaussians and active voxels of a cover of the selection's
            neighbourhood — from the view's kept binning when the renderer has one, else
            from the surfels that can blend before them (:mod:`.completion_gather`; the
            same records there, at a fraction of the full pass's cost); widened by the
            missing cells when the neighbourhood outgrows the cover (True; CPU only —
            elsewhere the full pass).
        gather_margin: coarse cells the cover reaches beyond the decision's first
            neighbourhood (the segmented voxels' cells dilated once and the selected
            Gaussians' cells), room for the fill to grow before a re-gather (2).
        gather_max_fraction: the sparse gather falls back to the full pass when the
            surfels that can blend before the cover exceed this share of the scene
            (0.5).
    """

    enabled: bool = True
    mask_threshold: float = 0.5
    gamma: float = 0.0
    min_weight: float = 0.01
    min_visibility: float = 0.1
    appearance_k: int = 0
    neighbourhood_log2: int = 1
    surface_margin: float = 2.0
    depth_factor: float = 1.0
    deep_is_inconsistent: bool = False
    fill_rounds: int = 8
    fill_min_views: int = 2
    centre_evidence: bool = False
    drop_inconsistent: bool = True
    drop_min_weight: float = 0.5
    sparse_gather: bool = True
    gather_margin: int = 2
    gather_max_fraction: float = 0.5

    def __post_init__(self) -> None:
        if not -1.0 < self.gamma < 1.0:
            raise ValueError(f"CompletionConfig.gamma must be in (-1, 1), got {self.gamma}")
        if not 0 <= self.neighbourhood_log2 <= 6:
            raise ValueError("CompletionConfig.neighbourhood_log2 must be in 0..6")
        for k in (
            "min_weight",
            "min_visibility",
            "drop_min_weight",
            "surface_margin",
            "depth_factor",
        ):
            if not getattr(self, k) >= 0:
                raise ValueError(f"CompletionConfig.{k} must be ≥ 0")
        if self.appearance_k < 0:
            raise ValueError("CompletionConfig.appearance_k must be ≥ 0")
        if self.fill_rounds < 0:
            raise ValueError("CompletionConfig.fill_rounds must be ≥ 0")
        if self.gather_margin < 0 or not 0.0 <= self.gather_max_fraction <= 1.0:
            raise ValueError(
                "CompletionConfig.gather_margin must be ≥ 0, gather_max_fraction in [0, 1]"
            )

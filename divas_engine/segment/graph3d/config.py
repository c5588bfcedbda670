"""Every constant of the 3D graph segmenter (:mod:`divas_engine.segment.graph3d`)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = ["Graph3DConfig", "WalkSolver"]


class WalkSolver(StrEnum):
    """How the walk's system is solved (:mod:`.walk_solver`)."""

    JACOBI_CG = "jacobi_cg"
    TWO_LEVEL = "two_level"


@dataclass(frozen=True)
class Graph3DConfig:
    """Knobs of the 3D graph segmenter (not in the paper). Symbols as in the
    design notes of :mod:`.voxel_graph` (docs/design-notes.md) and :mod:`.cut`.

    Region and graph:
        region_min: the smallest local region radius R, × the scene's robust radius
            ``r_fg`` (0.35): a single click looks this far around it.
        region_seed_factor: R is at least this × the spread of the positive seeds
            (the largest distance of a seed from their centre) (1.5).
        region_grow: R is multiplied by this when the chosen segment leans on the
            region's rim (2.0), at most ``region_max_grows`` (2) times.
        kept_clicks: with two or more positive clicks, the object's cut also keeps what
            the cuts of the seeds before each of the newest ``kept_clicks`` (2) positive
            clicks held (:meth:`.segmenter.Graph3DSegmenter.cut`): a positive click does
            not take back what the cut held; a negative click costs ``kept_clicks + 1``
            cuts.
        rim_share: "leans on the rim": the rim carries more than this share of the
            segment's cut (0.35). R also grows when the medium score is < 0.5 and the
            walk potential next to the rim exceeds ``rim_reach`` (1e-3).
        grid_cells: voxels along the region's diameter, ``h = 2R / grid_cells`` (96).
        extent_sigmas, extent_min_sigma, extent_gs3d_only: a Gaussian wider than a voxel
            (``σ_max > extent_min_sigma · h``, 1.0; a narrower one reaches only its
            voxel's neighbours, which the 26-neighbourhood links anyway) whose centre's
            voxel has no occupied neighbour (its centre leaves it unlinked) also occupies
            every voxel its ellipsoid ``|u| ≤ extent_sigmas`` (σ units, 1.0; 0: centres
            only) covers, with its opacity there ``α exp(−|u|²/2)``, sampled a voxel
            apart at most ``extent_max_steps`` (4) steps each way along an axis
            (:func:`.voxel_graph._extent_entries`): a large foliage Gaussian whose centre
            sits alone in its voxel is linked to what its footprint overlaps. Only on
            trained 3DGS scenes (``extent_gs3d_only``, True), where a large isolated
            Gaussian is a volume blob of the object. On 2DGS surfels an isolated centre
            is a sparsely sampled surface, and its extent would bridge an object to what
            it stands on (a vase to its plinth).
        min_opacity: primitives below this opacity are left out of the graph (0.02;
            near-invisible haze neither bridges objects nor shows in a mask).

    Affinities ``w_ij = a_d · a_c · a_n · a_m`` of adjacent voxels (26-neighbourhood):
        sigma_d: centroid distance scale, × h (1.0): ``a_d = exp(−|μ_i − μ_j|² / 2(σ_d h)²)``.
        colour_contrast: ``a_c = exp(−β |c_i − c_j|²)`` with β = colour_contrast /
            mean |Δc|² over the region's edges (GrabCut's contrast normalisation) (0.5).
        normal_sigma: ``a_n = exp(−ν_i ν_j (1 − agreement) / normal_sigma)``, agreement
            of the voxels' normal distributions, ν their confidence (0.15: two planes
            30° apart → 0.41, 60° → 0.04).
        mass_floor: ``a_m = m / (m + mass_floor · median m)``, m the smaller voxel mass
            (Σ opacity) (0.5): thin haze links weakly.

    Random walk and sweep:
        leak: ground-leak λ of every free voxel, × its degree (1e-5): a tie-break — the walk
            fades a little with graph distance, so of equally connected voxels the far
            ones rank last.
        cg_tol, cg_maxiter: conjugate-gradient tolerance and iteration cap.
        walk_solver: :class:`~.walk_solver.WalkSolver` — the two-level preconditioned
            CG (default: it reaches the tolerance in tens of steps) or the Jacobi CG
            (hundreds of steps; it stops short on near-islands, whose potentials then
            keep its starting guess).
        ground_band: a voxel within this × r_fg of a detected supporting plane whose
            normal is within ``ground_normal_deg`` of the plane's is a sink (0.02, 35°).
        support_min_voxels, support_min_share: a horizontal surface below the seeds
            with at least this many up-facing voxels (40) and this share of the region's
            voxels (0.02), ``support_min_width`` voxels wide (6), is a local support
            (:mod:`.supports`).
        min_granularity_ratio: the small / large channels differ from the medium one by
            at least this volume ratio (1.5); none → the medium itself.
        tie_window, tie_potential, clean_phi: the medium region is the smallest dip
            of φ (least within ± ``tie_window`` of its volume, 1.1) whose φ is within
            ``ambiguity_ratio`` of the least φ — any φ below ``clean_phi`` (1e-5: a cut
            of a hundredth of one strong edge per thousand of volume) is a clean
            separation, as good as 0 — when the voxels the least-φ region adds have a
            median walk potential below ``tie_potential`` (0.1) × the dip region's
            (:func:`.cut._first_tie`): of two regions equally well cut off, the one
            the walk reaches.
        min_region_share: the medium region holds at least this share of the graph's
            volume (0.01): a speck of haze cut off around the click is not the object.
        drop_supports, support_quantile: the medium region is the largest smaller dip
            that stands on what the least-φ region adds beyond it (all but
            ``support_quantile`` (0.05) of the added voxels below the boundary, as many
            of the dip's above it; :func:`.cut._on_its_support`): a statue's pedestal of
            another material, a guitar's stand. Needs the scene's up (True).
        negative_claims: the voxels a walk from the negative seeds reaches before the
            positive ones leave the sweep like sinks (:func:`.cut._claimed`, Grady's
            two-label walker; True): a negative click on the pedestal removes the
            pedestal, not one voxel of it.

    Scores and mask:
        score_contrast: boundary contrast c₀ at which the score is 0.5 (0.35); score =
            1/(1+(c/c₀)²) (:mod:`.cut` step 4).
        neck_min_voxels: the contrast is scaled by the cut's narrowness (:mod:`.cut`
            step 4) only when its boundary holds at least this many voxels (0: always).
            An object resting against another touches it in a few voxels, and that
            contact is its boundary: a guitar leaning on its stand is cut off along a
            handful of boundary voxels, and a threshold above that would score the
            clean cut low enough for its views to be rejected.
        ambiguity_ratio: another sweep minimum within this φ ratio of the best and at a
            different size makes the cut ambiguous (1.3): the score is scaled by
            ``ambiguity_penalty`` (0.6). φ's below ``clean_phi`` count as equal; a
            larger minimum that only adds a piece not touching the region (an object
            beside it) is no rival.
        low_res: longest side of the mask render (256, SAM's low-res logit grid).
        logit_scale: logits = logit_scale · (coverage − 0.5) (8, as the oracle).
    """

    region_min: float = 0.35
    region_seed_factor: float = 1.5
    region_grow: float = 2.0
    region_max_grows: int = 2
    kept_clicks: int = 2
    rim_share: float = 0.35
    rim_reach: float = 1e-3
    grid_cells: int = 96
    min_opacity: float = 0.02
    extent_sigmas: float = 1.0
    extent_max_steps: int = 4
    extent_min_sigma: float = 1.0
    extent_gs3d_only: bool = True
    sigma_d: float = 1.0
    colour_contrast: float = 0.5
    normal_sigma: float = 0.15
    mass_floor: float = 0.5
    leak: float = 1e-5
    cg_tol: float = 1e-5
    cg_maxiter: int = 400
    walk_solver: WalkSolver = WalkSolver.TWO_LEVEL
    ground_band: float = 0.02
    ground_normal_deg: float = 35.0
    support_min_voxels: int = 40
    support_min_share: float = 0.02
    support_min_width: float = 6.0
    min_granularity_ratio: float = 1.5
    min_region_share: float = 0.01
    drop_supports: bool = True
    negative_claims: bool = True
    support_quantile: float = 0.05
    tie_window: float = 1.1
    clean_phi: float = 1e-5
    tie_potential: float = 0.1
    score_contrast: float = 0.35
    neck_min_voxels: int = 0
    ambiguity_ratio: float = 1.3
    ambiguity_penalty: float = 0.6
    low_res: int = 256
    logit_scale: float = 8.0

"""Peer baselines for the evaluation: lift the *same* accepted 2D view masks that DivAS
fused to a per-surfel selection without DivAS's voxel fusion and mapping.

Both take :class:`MaskView` lists; a pixel is positive when ``m ≥ mask_threshold`` (0.5).

(a) :func:`centre_vote` — centre-projection majority voting. A surfel is *seen* when its centre
    projects inside the image, beyond the near plane, and is not hidden: ``D_med = 0`` there or
    ``z ≤ D_med · (1 + depth_rel_tol) + scale_tol · max(s₁, s₂)`` (one-sided). It is foreground
    iff its positive votes are a strict majority of the views that see it.

(b) :func:`contribution_vote` — contribution-weighted voting in the style of FlashSplat (Shen
    et al., ECCV 2024): with ``A₁ = Σ α T`` over mask-positive pixels and ``A₀`` over negative
    ones (all views, the rasterizer's own weights), a surfel is foreground iff

        A₁ / ‖A‖ > A₀ / ‖A‖ + γ,   ‖A‖ = √(A₀² + A₁²)

    FlashSplat's binary solver with background bias γ ("slackness"), γ ∈ (−1, 1), default 0
    (their default; larger values suit object removal). Surfels with no contribution are
    background.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from divas_kernels import resolve_device

from ..camera import Camera
from ..render import RenderConfig, make_renderer
from ..render.surfel_renderer import SurfelRenderer
from ..scene import SurfelScene

__all__ = [
    "MaskView",
    "BaselineResult",
    "CentreVoteConfig",
    "centre_vote",
    "ContributionVoteConfig",
    "ContributionVoter",
    "contribution_vote",
    "flashsplat_foreground",
    "as_mask_views",
]


@dataclass(eq=False)
class MaskView:
    """One accepted view: its camera, mask ``[H,W]`` (probabilities) and optionally its
    rendered ``D_med`` ``[H,W]`` (rendered on demand by :func:`centre_vote`)."""

    camera: Camera
    mask: np.ndarray
    d_med: np.ndarray | None = None

    def __post_init__(self) -> None:
        m = np.asarray(self.mask)
        if m.shape != (self.camera.height, self.camera.width):
            raise ValueError(
                f"MaskView: mask {m.shape} does not match the "
                f"{self.camera.width}x{self.camera.height} camera"
            )
        if self.d_med is not None and np.shape(self.d_med) != m.shape:
            raise ValueError(f"MaskView: D_med {np.shape(self.d_med)} vs mask {m.shape}")


def as_mask_views(views) -> list[MaskView]:
    """Normalise ``MaskView`` / ``(camera, mask)`` / ``(camera, mask, d_med)`` items."""
    out = []
    for v in views:
        out.append(v if isinstance(v, MaskView) else MaskView(*v))
    return out


@dataclass(eq=False)
class BaselineResult:
    """A baseline's selection and its per-surfel evidence.

    Attributes:
        selected: ``[N]`` bool.
        positive, negative: (a) views voting positive / seen-but-negative (int);
            (b) A₁ / A₀ (float64).
        seconds: wall time.
    """

    selected: np.ndarray
    positive: np.ndarray
    negative: np.ndarray
    seconds: float = 0.0
    info: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- (a)
@dataclass(frozen=True)
class CentreVoteConfig:
    """Constants of :func:`centre_vote` (module docstring).

    Attributes:
        mask_threshold: mask-positive pixel ``m ≥`` this (0.5).
        depth_rel_tol: relative depth tolerance of the visibility test (0.01).
        scale_tol: absolute tolerance in multiples of the surfel's larger scale (2).
        near: in front of the camera: planar depth ``>`` this (the renderer's near, 0.01),
            or the view camera's own larger near (``Camera.clip_near``).
    """

    mask_threshold: float = 0.5
    depth_rel_tol: float = 0.01
    scale_tol: float = 2.0
    near: float = 0.01


def centre_vote(
    scene: SurfelScene,
    views: Sequence,
    *,
    config: CentreVoteConfig = CentreVoteConfig(),
    renderer=None,
    device=None,
) -> BaselineResult:
    """Baseline (a): centre-projection majority voting (module docstring)."""
    t0 = time.perf_counter()
    mv = as_mask_views(views)
    n = len(scene)
    means = scene.means.astype(np.float64)
    smax = np.asarray(scene.scales, np.float64).max(axis=1)
    pos = np.zeros(n, np.int32)
    neg = np.zeros(n, np.int32)
    r = renderer
    for v in mv:
        cam = v.camera
        d_med = v.d_med
        if d_med is None:
            if r is None:
                r = make_renderer(scene, device=device)
            d_med = r.render(cam).D_med
        uv, z = cam.project(means)
        inside = cam.in_image(uv, z, cam.clip_near(config.near))
        idx = np.flatnonzero(inside)
        x = np.floor(uv[idx, 0]).astype(np.int64)
        y = np.floor(uv[idx, 1]).astype(np.int64)
        x = np.minimum(x, cam.width - 1)  # guard float rounding at the border
        y = np.minimum(y, cam.height - 1)
        d = np.asarray(d_med, np.float64)[y, x]
        tol = d * config.depth_rel_tol + config.scale_tol * smax[idx]
        seen = (d <= 0) | (z[idx] <= d + tol)
        m = np.asarray(v.mask)[y, x] >= np.float32(config.mask_threshold)
        ids = idx[seen]
        pos[ids[m[seen]]] += 1
        neg[ids[~m[seen]]] += 1
    sel = pos > neg
    return BaselineResult(
        sel,
        pos,
        neg,
        time.perf_counter() - t0,
        {"views": len(mv), "seen": int(np.count_nonzero(pos + neg))},
    )


# ----------------------------------------------------------------------------- (b)
@dataclass(frozen=True)
class ContributionVoteConfig:
    """Constants of :func:`contribution_vote` (module docstring).

    Attributes:
        mask_threshold: mask-positive pixel ``m ≥`` this (0.5).
        gamma: background bias γ ∈ (−1, 1) on the L2-normalised pair: foreground iff
            ``A₁ − A₀ > γ √(A₀² + A₁²)`` (0, FlashSplat's default).
    """

    mask_threshold: float = 0.5
    gamma: float = 0.0

    def __post_init__(self) -> None:
        if not -1.0 < self.gamma < 1.0:
            raise ValueError(f"ContributionVoteConfig.gamma must be in (-1, 1), got {self.gamma}")


def flashsplat_foreground(a1: np.ndarray, a0: np.ndarray, gamma: float) -> np.ndarray:
    """FlashSplat's binary rule with background bias γ: ``A₁/‖A‖ > A₀/‖A‖ + γ`` with
    ``‖A‖ = √(A₀² + A₁²)``; a Gaussian with no weight is background."""
    a1 = np.asarray(a1, np.float64)
    a0 = np.asarray(a0, np.float64)
    return (a1 - a0 > gamma * np.hypot(a0, a1)) & (a0 + a1 > 0)


class ContributionVoter:
    """Baseline (b) for one scene: the surfels are uploaded once; :meth:`vote` per view set.

    Args:
        render_config: the renderer constants (α_min, α_max, T_min, near, low-pass σ,
            tile, blend form) — the weights are the renderer's.
    """

    def __init__(self, scene: SurfelScene, device=None, render_config: RenderConfig | None = None):
        self.device = resolve_device(device)
        self.render_config = render_config or RenderConfig()
        self.n = len(scene)
        self._renderer = SurfelRenderer(scene, self.device, self.render_config)

    def contributions(
        self, view: MaskView, mask_threshold: float = 0.5
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(A₁, A₀)`` ``[N]`` float32 of one view."""
        cam = view.camera
        positive = np.asarray(view.mask) >= np.float32(mask_threshold)
        out = self._renderer.contributions(cam, positive)
        return out.a1.numpy(), out.a0.numpy()

    def vote(
        self, views: Sequence, config: ContributionVoteConfig = ContributionVoteConfig()
    ) -> BaselineResult:
        t0 = time.perf_counter()
        mv = as_mask_views(views)
        a1 = np.zeros(self.n, np.float64)
        a0 = np.zeros(self.n, np.float64)
        for v in mv:
            p, q = self.contributions(v, config.mask_threshold)
            a1 += p
            a0 += q
        sel = flashsplat_foreground(a1, a0, config.gamma)
        return BaselineResult(
            sel,
            a1,
            a0,
            time.perf_counter() - t0,
            {
                "views": len(mv),
                "gamma": config.gamma,
                "contributing": int(np.count_nonzero(a0 + a1 > 0)),
            },
        )


def contribution_vote(
    scene: SurfelScene,
    views: Sequence,
    *,
    config: ContributionVoteConfig = ContributionVoteConfig(),
    device=None,
    render_config: RenderConfig | None = None,
) -> BaselineResult:
    """Baseline (b): contribution-weighted voting (module docstring), one-shot form."""
    return ContributionVoter(scene, device, render_config).vote(views, config)

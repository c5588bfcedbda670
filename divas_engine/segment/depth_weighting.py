"""Depth weighting of SAM masks (paper Sec. 3.4 "Depth-weighting").

NeRF — bounded min-max normalisation (eq:nerf-depthweight)::

    M̃_s = M_s ⊙ (1 − Ẑ_s),   Ẑ_s = (D_exp − min D_exp) / max(max D_exp − min D_exp, floor)

2DGS — prompt depth band with a robust far estimate (eq:depthband, eq:gs-bandpass)::

    𝒟_s = {D_med(p_k)}_{k=1..P_s} ∪ {D_med(w/2, h/2)},  d_min = min 𝒟_s,  d_max = max 𝒟_s
    d_far = 𝒫₉₈(D_med)
    Δ₋ = max(d_min − D_med, 0),  Δ₊ = max(D_med − d_max, 0)
    D_band = clip((Δ₋ + Δ₊) / max(d_far − d_max, 10⁻⁶), 0, 1),   M̃_s = M_s (1 − D_band)

``p_k`` are the positive prompts, read at the pixel containing them (``floor``). Min, max and
``𝒫₉₈`` are over valid pixels: finite and ``≥ min_valid_depth``, optionally ANDed with a caller
mask. Invalid pixels get ``invalid_weight`` (0): the paper's formulas do not define them and
the fusion kernels skip them; the floor keeps a constant-depth view at weight 1, not 0/0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import as_prompts, pixel_index

__all__ = [
    "NerfDepthWeightConfig",
    "GsBandpassConfig",
    "DepthBand",
    "valid_depth",
    "nerf_depth_weight",
    "apply_nerf_depth_weight",
    "depth_band",
    "gs_bandpass_weight",
    "apply_gs_bandpass",
]


@dataclass(frozen=True)
class NerfDepthWeightConfig:
    """eq:nerf-depthweight constants.

    Attributes:
        denom_floor: floor of ``max(D_exp) − min(D_exp)`` (10⁻⁶, as in eq:gs-bandpass).
        min_valid_depth: ``ε``; ``D_exp < ε`` or non-finite is invalid.
        invalid_weight: weight of invalid pixels.
    """

    denom_floor: float = 1e-6
    min_valid_depth: float = 1e-6
    invalid_weight: float = 0.0


@dataclass(frozen=True)
class GsBandpassConfig:
    """eq:depthband / eq:gs-bandpass constants.

    Attributes:
        far_percentile: ``𝒫₉₈`` — the percentile giving ``d_far``.
        denom_floor: the ``10⁻⁶`` floor of ``d_far − d_max``.
        include_view_center: add ``D_med(w/2, h/2)`` to ``𝒟_s`` (eq:depthband).
        min_valid_depth: ``ε``; ``D_med < ε`` or non-finite is invalid (NOTES).
        invalid_weight: weight of invalid pixels.
    """

    far_percentile: float = 98.0
    denom_floor: float = 1e-6
    include_view_center: bool = True
    min_valid_depth: float = 1e-6
    invalid_weight: float = 0.0


@dataclass(frozen=True)
class DepthBand:
    """``[d_min, d_max]`` of eq:depthband, ``d_far`` and the sample set ``𝒟_s``."""

    d_min: float
    d_max: float
    d_far: float
    samples: np.ndarray

    @property
    def denominator(self) -> float:
        """``d_far − d_max`` before flooring."""
        return self.d_far - self.d_max


def valid_depth(
    depth: np.ndarray, min_valid_depth: float, valid: np.ndarray | None = None
) -> np.ndarray:
    """Finite and ``≥ min_valid_depth`` (and ``valid`` when given)."""
    d = np.asarray(depth)
    ok = np.isfinite(d) & (d >= min_valid_depth)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    return ok


def nerf_depth_weight(
    depth: np.ndarray, valid: np.ndarray | None = None, config: NerfDepthWeightConfig | None = None
) -> np.ndarray:
    """``1 − Ẑ_s`` of eq:nerf-depthweight, ``[H,W]`` float32."""
    cfg = config or NerfDepthWeightConfig()
    d = np.asarray(depth, dtype=np.float64)
    ok = valid_depth(d, cfg.min_valid_depth, valid)
    weight = np.full(d.shape, cfg.invalid_weight, np.float64)
    if ok.any():
        lo, hi = d[ok].min(), d[ok].max()
        z = (d[ok] - lo) / max(hi - lo, cfg.denom_floor)
        weight[ok] = 1.0 - np.clip(z, 0.0, 1.0)
    return weight.astype(np.float32)


def apply_nerf_depth_weight(
    mask: np.ndarray,
    depth: np.ndarray,
    valid: np.ndarray | None = None,
    config: NerfDepthWeightConfig | None = None,
) -> np.ndarray:
    """``M̃_s = M_s ⊙ (1 − Ẑ_s)`` (eq:nerf-depthweight)."""
    m = np.asarray(mask, dtype=np.float32)
    if m.shape != np.shape(depth):
        raise ValueError(f"mask {m.shape} and depth {np.shape(depth)} differ in shape")
    return m * nerf_depth_weight(depth, valid, config)


def depth_band(
    depth: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    valid: np.ndarray | None = None,
    config: GsBandpassConfig | None = None,
) -> DepthBand | None:
    """``d_min, d_max`` (eq:depthband) and ``d_far = 𝒫₉₈(D_med)``; None without a valid sample."""
    cfg = config or GsBandpassConfig()
    d = np.asarray(depth, dtype=np.float64)
    h, w = d.shape
    ok = valid_depth(d, cfg.min_valid_depth, valid)
    p, lab = as_prompts(points, labels)
    pts = p[lab == 1]
    if cfg.include_view_center:
        pts = np.concatenate([pts, [[w / 2.0, h / 2.0]]], axis=0)
    rows, cols = pixel_index(pts, (h, w))
    keep = ok[rows, cols]
    samples = d[rows[keep], cols[keep]]
    if samples.size == 0 or not ok.any():
        return None
    d_far = float(np.percentile(d[ok], cfg.far_percentile))
    return DepthBand(float(samples.min()), float(samples.max()), d_far, samples)


def gs_bandpass_weight(
    depth: np.ndarray,
    band: DepthBand,
    valid: np.ndarray | None = None,
    config: GsBandpassConfig | None = None,
) -> np.ndarray:
    """``1 − D_band`` of eq:gs-bandpass, ``[H,W]`` float32."""
    cfg = config or GsBandpassConfig()
    d = np.asarray(depth, dtype=np.float64)
    ok = valid_depth(d, cfg.min_valid_depth, valid)
    delta_minus = np.maximum(band.d_min - d, 0.0)
    delta_plus = np.maximum(d - band.d_max, 0.0)
    denom = max(band.d_far - band.d_max, cfg.denom_floor)
    with np.errstate(invalid="ignore", over="ignore"):
        d_band = np.clip((delta_minus + delta_plus) / denom, 0.0, 1.0)
    return np.where(ok, 1.0 - d_band, cfg.invalid_weight).astype(np.float32)


def apply_gs_bandpass(
    mask: np.ndarray,
    depth: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    valid: np.ndarray | None = None,
    config: GsBandpassConfig | None = None,
) -> tuple[np.ndarray, DepthBand | None]:
    """``M̃_s = M_s (1 − D_band)`` (eq:gs-bandpass) and the band used.

    Without a valid band sample the mask is returned unweighted with band None.
    """
    m = np.asarray(mask, dtype=np.float32)
    if m.shape != np.shape(depth):
        raise ValueError(f"mask {m.shape} and depth {np.shape(depth)} differ in shape")
    band = depth_band(depth, points, labels, valid, config)
    if band is None:
        return m.copy(), None
    return m * gs_bandpass_weight(depth, band, valid, config), band

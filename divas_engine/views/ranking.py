"""Geometric view ranking (paper App. C.2, alg:view_ranking).

For unit directions d_i (the direction from the scene centre to the candidate
camera) expressed in the up-aligned frame (NOTES "Anchors": canonical axes and
pitch are relative to the scene up):

* D_i = 1/(N−1) Σ_{j≠i} (1 − d_i·d_j)          diversity
* C_i = max_{a ∈ {±x,±y,±z}} 1 / (‖d_i − a‖ + ε)   cardinal coverage
* P_i = |θ_i| / 90°, θ_i = elevation of d_i above the horizontal plane
* each of D, C, P min–max normalised to [0, 1] over the candidates (a constant
  component normalises to 0: it cannot change the order);
* I_i = w_d D_i + w_c C_i + w_p P_i; ties keep the candidate order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import ViewConfig

__all__ = ["Ranking", "rank_directions", "minmax"]


@dataclass(frozen=True)
class Ranking:
    """Per-candidate scores (raw and normalised) and the order best → worst."""

    D_raw: np.ndarray
    C_raw: np.ndarray
    P_raw: np.ndarray
    D: np.ndarray
    C: np.ndarray
    P: np.ndarray
    score: np.ndarray
    order: np.ndarray


def minmax(x: np.ndarray) -> np.ndarray:
    """Min–max normalisation to [0, 1]; a constant vector maps to zeros."""
    x = np.asarray(x, dtype=np.float64)
    span = x.max() - x.min() if x.size else 0.0
    return np.zeros_like(x) if span <= 1e-15 else (x - x.min()) / span


def rank_directions(local_dirs: np.ndarray, config: ViewConfig | None = None) -> Ranking:
    """Score ``[N,3]`` unit directions given in the up-aligned frame (+z = up)."""
    cfg = config or ViewConfig()
    d = np.asarray(local_dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = len(d)
    if n < 1:
        raise ValueError("rank_directions: no candidates")
    cos = d @ d.T
    D_raw = (1.0 - cos).sum(1) / max(n - 1, 1)  # the j = i term is 1 − 1 = 0
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    dist = np.linalg.norm(d[:, None, :] - axes[None], axis=2)
    C_raw = (1.0 / (dist + cfg.cardinal_eps)).max(1)
    elev = np.degrees(np.arcsin(np.clip(d[:, 2], -1.0, 1.0)))
    P_raw = np.abs(elev) / 90.0
    D, C, P = minmax(D_raw), minmax(C_raw), minmax(P_raw)
    score = cfg.w_diversity * D + cfg.w_cardinal * C + cfg.w_pitch * P
    order = np.argsort(-score, kind="stable")
    return Ranking(D_raw, C_raw, P_raw, D, C, P, score, order)

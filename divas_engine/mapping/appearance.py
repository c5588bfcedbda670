"""Appearance consistency of Gaussians seen only through other surfaces — a decision rule
of the 3DGS completion (:mod:`divas_engine.mapping.completion`; beyond the paper).

A contribution-positive Gaussian that no fused view *sees* (``min_visibility``) has its
blending weight inside the silhouettes only because what covers it is the object. Two
very different things are in that state: the object's own inside or back, seen through
its front (large translucent Gaussians behind a plant's leaves), and the support or the
background behind the object (the table seen through a pot). Their geometry in the views
is the same; their *appearance* is not: a hidden part of the object has the colour of
the object's seen Gaussians next to it, the support behind it has the colour of the
support's seen Gaussians next to it — the support continues beyond the silhouette, where
the views see it and the masks leave it out.

:func:`appearance_votes` states that rule: among the ``k`` *seen* Gaussians nearest in
3D to a candidate (seen in some fused view, with contribution evidence), take the one
whose colour (SH DC, :meth:`~divas_engine.scene.SurfelScene.base_colors`) is closest to
the candidate's; the candidate joins when that Gaussian is in the selection. It reads
only the completion's integer counters and the scene (no per-view array), so the
decision stays exact under undo.
"""

from __future__ import annotations

import numpy as np

__all__ = ["appearance_votes", "seen_through_like_object"]


def appearance_votes(
    cand: np.ndarray,
    ref: np.ndarray,
    ref_in_object: np.ndarray,
    means: np.ndarray,
    colors: np.ndarray,
    k: int,
) -> np.ndarray:
    """``[len(cand)] bool``: candidate Gaussians ``cand`` (indices) whose colour-nearest
    among their ``k`` spatially nearest reference Gaussians ``ref`` (indices; the seen
    Gaussians of the neighbourhood) is an object one (``ref_in_object`` ``[len(ref)]``).
    No reference or no object reference: False (nothing to be consistent with)."""
    cand = np.asarray(cand, np.int64)
    ref = np.asarray(ref, np.int64)
    out = np.zeros(len(cand), bool)
    if len(cand) == 0 or len(ref) == 0 or not np.any(ref_in_object):
        return out
    from scipy.spatial import cKDTree

    kk = int(min(max(k, 1), len(ref)))
    _, nb = cKDTree(means[ref]).query(means[cand], k=kk)
    nb = np.asarray(nb, np.int64).reshape(len(cand), kk)
    dc = colors[ref[nb]] - colors[cand][:, None, :]  # [c, k, 3]
    d2 = (dc * dc).sum(axis=2)
    d2[ref[nb] == cand[:, None]] = np.inf  # a candidate is no reference for itself
    best = np.argmin(d2, axis=1)  # first on ties: the nearest in 3D
    return np.asarray(ref_in_object, bool)[nb[np.arange(len(cand)), best]]


def seen_through_like_object(
    comp, cand: np.ndarray, obj: np.ndarray, near: np.ndarray, min_q: float
) -> np.ndarray:
    """:func:`appearance_votes` for the candidates ``cand`` of a
    :class:`~divas_engine.mapping.completion.VolumetricCompletion` ``comp``: the
    references are the *seen* Gaussians (``n_seen ≥ 1``, fixed-point weight ``q₀ + q₁ ≥
    min_q``) of the neighbourhood ``near`` (``[N] bool``) in the candidates' coarse cells
    and the cells next to them (local: no tree over the whole neighbourhood); ``obj``
    ``[N] bool`` says which Gaussians are the object's; ``comp.config.appearance_k``."""
    cells = comp.cells
    cand_cells = cells.dilate_cells(np.zeros(cells.n + 1, bool), cells.of_gauss[cand])
    ref = cells.gaussians_in(cand_cells)
    ref = ref[near[ref] & (comp.n_seen[ref] >= 1)]
    ref = ref[(comp.q1[ref] + comp.q0[ref]) >= min_q]
    k = comp.config.appearance_k
    return appearance_votes(cand, ref, obj[ref], comp.means, comp.colors, k)

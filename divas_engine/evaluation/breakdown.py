"""Where a 3DGS selection's errors come from (diagnostics): the true and false
Gaussians of a DivAS selection split by the step that put them there — the paper's passes
(Pass 3's selection ``f``, less what the completion dropped), the completion's
contribution additions and its fill additions — counted and weighted by opacity (the
weight of the opacity-weighted Gaussian IoU, :func:`.fidelity.weighted_iou`), with the
opacity-weighted IoU the selection would have without each source's false Gaussians.

Used by ``benchmarks/bench_real_captures.py --breakdown`` (e.g. to read guitar/stand's
false positives).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .fidelity import weighted_iou

__all__ = ["SOURCES", "completion_sources", "source_breakdown"]

#: the sources of a completed selection, in the order they are reported
SOURCES = ("paper", "contribution", "fill")


def completion_sources(
    mapped: np.ndarray, contrib_added: np.ndarray, fill_added: np.ndarray, dropped: np.ndarray
) -> dict[str, np.ndarray]:
    """``{source: [N] bool}`` of a completed selection ``(mapped − dropped) ∪ contrib ∪
    fill`` (:class:`~divas_engine.mapping.completion.CompletionResult`): the three parts
    are disjoint (the completion adds only unselected Gaussians) and their union is the
    selection."""
    m = np.asarray(mapped, bool) & ~np.asarray(dropped, bool)
    c = np.asarray(contrib_added, bool) & ~m
    f = np.asarray(fill_added, bool) & ~m & ~c
    return {"paper": m, "contribution": c, "fill": f}


def source_breakdown(
    selection: np.ndarray,
    labels: np.ndarray,
    weights: np.ndarray,
    sources: Mapping[str, np.ndarray],
) -> dict[str, dict[str, float]]:
    """Per source (and ``"missed"``, the true Gaussians not selected): ``tp``, ``fp``
    (counts of the source's selected true / false Gaussians), ``tp_w``, ``fp_w`` (their
    summed ``weights``) and ``iou_without_fp`` (the ``weights``-IoU of the selection with
    that source's false Gaussians removed). ``"missed"`` carries ``fn`` / ``fn_w``.
    A selected Gaussian in no source is reported under ``"other"`` (none when the sources
    come from :func:`completion_sources`)."""
    s = np.asarray(selection, bool)
    g = np.asarray(labels, bool)
    w = np.asarray(weights, np.float64)
    if not (s.shape == g.shape == w.shape):
        raise ValueError(f"source_breakdown: shapes {s.shape}, {g.shape}, {w.shape} differ")
    out: dict[str, dict[str, float]] = {}
    covered = np.zeros_like(s)
    parts = {k: np.asarray(v, bool) & s for k, v in sources.items()}
    rest = s.copy()
    for v in parts.values():
        rest &= ~v
    if rest.any():
        parts["other"] = rest
    for name, part in parts.items():
        part = part & ~covered  # a Gaussian counts for the first source that holds it
        covered |= part
        fp = part & ~g
        out[name] = {
            "tp": int((part & g).sum()),
            "fp": int(fp.sum()),
            "tp_w": float(w[part & g].sum()),
            "fp_w": float(w[fp].sum()),
            "iou_without_fp": weighted_iou(s & ~fp, g, w),
        }
    fn = g & ~s
    out["missed"] = {"fn": int(fn.sum()), "fn_w": float(w[fn].sum())}
    return out

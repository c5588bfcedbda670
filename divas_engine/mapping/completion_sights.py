"""Views that share a sight count once in the completion's view counts.

The solid fill takes a voxel hidden behind mask-positive surfaces only when
``fill_min_views`` views hold it (:class:`~.config.CompletionConfig`): two visual cones
meet in a bounded region, one cone alone does not. A wider view of a click (the session's
``<view id>:w<k>``, :mod:`divas_engine.session.widening`) looks at the same point along
the same direction from farther away: its cone is its close-up's cone, so the pair is one
sight, and counting it twice fills everything the close-up hides behind the object (a
guitar's stand behind its body). Each count here is the number of *sights* with the
evidence; it is computed from the live records at decision time, so add, remove and undo
stay exact.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence

import numpy as np

from .completion_records import HIDDEN, SURFACE, _ViewRecord

__all__ = ["shared_sights", "voxel_repeats", "deep_repeats"]


def shared_sights(sights: Mapping[int, Hashable], live: Sequence[int]) -> list[list[int]]:
    """The groups of two or more ``live`` view keys with the same sight (a key missing
    from ``sights`` is a sight of its own)."""
    groups: dict[Hashable, list[int]] = {}
    for k in live:
        groups.setdefault(sights.get(k, ("own", k)), []).append(k)
    return [g for g in groups.values() if len(g) > 1]


def _repeats(
    groups: list[list[int]],
    hits: Mapping[int, np.ndarray],
    query: np.ndarray,
) -> np.ndarray:
    """``[len(query)]`` int32: over the groups, the members holding each queried index
    (``hits[key]``: the indices a member's record holds the evidence for) less one, when
    more than one does — what a per-view count says beyond a per-sight one."""
    out = np.zeros(len(query), np.int32)
    for g in groups:
        n = np.zeros(len(query), np.int32)
        for k in g:
            n += np.isin(query, hits[k]).astype(np.int32)
        out += np.maximum(n - 1, 0)
    return out


def voxel_repeats(
    groups: list[list[int]], records: Mapping[int, _ViewRecord], vox: np.ndarray
) -> np.ndarray:
    """How much ``n_surf + n_hidden`` of voxels ``vox`` over-counts their sights."""
    hits = {}
    for g in groups:
        for k in g:
            r = records[k]
            hits[k] = r.voxels[(r.flags == SURFACE) | (r.flags == HIDDEN)]
    return _repeats(groups, hits, np.asarray(vox))


def deep_repeats(
    groups: list[list[int]], records: Mapping[int, _ViewRecord], gauss: np.ndarray
) -> np.ndarray:
    """How much ``n_deep_ok`` of Gaussians ``gauss`` over-counts their sights."""
    hits = {k: records[k].gauss[records[k].deep > 0] for g in groups for k in g}
    return _repeats(groups, hits, np.asarray(gauss))

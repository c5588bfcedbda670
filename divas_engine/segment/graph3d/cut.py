"""Seeded random walk and sweep cut on the local voxel graph: three nested regions.

The positive seed voxels hold ``x = 1``; the negative seeds, the region's rim and the
supporting surfaces are sinks; every free voxel leaks ``λ · deg`` to 0 (Grady's random
walk with a prior): ``(L_UU + λ D_U) x_U = W_UF 1``. Sorting the voxels by ``x``, the
prefix of least conductance ``φ(S) = cut(S) / min(vol(S), vol(V) − vol(S))`` is the
medium region (a sweep cut: no shrinking bias on thin parts); the best local minima of
φ smaller and larger are the small and large ones (SAM's nested granularities). The
score is the boundary's contrast ``c`` (cut-edge over inside affinity, times the cut's
narrowness): ``1 / (1 + (c / c₀)²)``, times ``1 − rim share`` and an ambiguity penalty.
The steps in full: ``docs/design-notes.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.ndimage import minimum_filter1d
from scipy.sparse.csgraph import connected_components

from .config import Graph3DConfig
from .voxel_graph import VoxelGraph, other_material
from .walk_solver import solve_walk

__all__ = ["CutResult", "Granularity", "walk_potential", "sweep_cut"]

_LOG_BINS = 256
_MAX_RING_SEEDS = 32  # seeds whose surroundings must be in the region (the rest: the voxel)


@dataclass(frozen=True, eq=False)
class Granularity:
    """One nested region: ``nodes`` bool ``[V]``, its conductance ``phi``, ``score``,
    ``volume`` and boundary ``contrast`` (cut-edge over inside-edge mean affinity)."""

    nodes: np.ndarray
    phi: float
    score: float
    volume: float
    contrast: float = 0.0


@dataclass(frozen=True, eq=False)
class CutResult:
    """Three granularities small → large, the walk potential and diagnostics.

    Attributes:
        levels: 3 :class:`Granularity` (small, medium, large; nested).
        potential: ``[V]`` walk potential x.
        rim_share: share of the medium region's cut that goes to the rim (the region
            was too small when high).
        ambiguous: another sweep minimum of a different size was nearly as good.
        alternative: volume ratio of that competing region to the medium one (> 1:
            larger), or None.
    """

    levels: tuple[Granularity, Granularity, Granularity]
    potential: np.ndarray
    rim_share: float
    ambiguous: bool
    alternative: float | None


def _laplacian(graph: VoxelGraph) -> tuple[sparse.csr_matrix, np.ndarray]:
    v = len(graph)
    e, w = graph.edges, graph.weights
    rows, cols = np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]]
    wmat = sparse.csr_matrix((np.r_[w, w], (rows, cols)), shape=(v, v))
    deg = np.asarray(wmat.sum(axis=1)).ravel()
    return wmat, deg


def walk_potential(
    graph: VoxelGraph, positive: np.ndarray, sinks: np.ndarray, config: Graph3DConfig
) -> tuple[np.ndarray, sparse.csr_matrix, np.ndarray]:
    """Walk potential ``x [V]`` (step 1), the affinity matrix and the degrees.

    Solved for the escape probability ``u = 1 − x``:
    ``(L_UU + λ D_U) u = λ deg_U + W_U,sinks 1``, so that inside an island (no sink
    reachable, ``u = O(λ)``) the tolerance is relative to ``u`` and its ordering —
    graph distance from the seeds — survives. Voxels with no edge are sinks, and so is
    every part of the graph that holds no positive seed: there ``x = 0`` exactly (the
    leaky system's solution ``u = 1``), which an iterative solve started at ``u ≈ λ``
    would only approach after far more iterations than the cap — a loose speck of the
    floor next to the object would keep a spurious high ``x`` and be swept in."""
    wmat, deg = _laplacian(graph)
    v = len(graph)
    u = np.ones(v)
    u[positive] = 0.0
    free = ~(positive | sinks) & (deg > 0) & _seeded_parts(wmat, positive)
    fi = np.flatnonzero(free)
    if len(fi) == 0:
        return 1.0 - u, wmat, deg
    rows = wmat[fi]
    w_uu = rows[:, fi]
    to_sinks = np.flatnonzero(~positive & ~free)
    b = config.leak * deg[fi] + np.asarray(rows[:, to_sinks].sum(axis=1)).ravel()
    diag = deg[fi] * (1.0 + config.leak)
    a = sparse.diags(diag) - w_uu
    x0 = np.clip(b / diag, 0.0, 1.0)
    sol = solve_walk(a, b, diag, x0, graph.cell[fi], config)
    u[fi] = np.clip(sol, 0.0, 1.0)
    return 1.0 - u, wmat, deg


def _seeded_parts(wmat: sparse.csr_matrix, positive: np.ndarray) -> np.ndarray:
    """Bool ``[V]``: the voxels of the connected parts of the graph that hold a positive
    seed."""
    _, part = connected_components(wmat > 0, directed=False)
    return np.isin(part, np.unique(part[positive]))


def _prefix_cuts(order: np.ndarray, graph: VoxelGraph, deg: np.ndarray) -> np.ndarray:
    """``cut(S_k)`` for k = 1 … V where ``S_k`` = the first k nodes of ``order``."""
    v = len(order)
    rank = np.empty(v, np.int64)
    rank[order] = np.arange(v)
    e, w = graph.edges, graph.weights
    ra, rb = rank[e[:, 0]], rank[e[:, 1]]
    lo, hi = np.minimum(ra, rb), np.maximum(ra, rb)
    # edge (lo, hi) is cut for prefixes of size k with lo < k <= hi, i.e. k-1 in [lo, hi);
    # one bincount adds in the order two np.add.at calls would (the same sums, faster)
    diff = np.bincount(np.r_[lo, hi], np.r_[w, -w], v + 1)
    return np.cumsum(diff)[:v]


def sweep_cut(
    graph: VoxelGraph,
    positive: np.ndarray,
    sinks: np.ndarray,
    config: Graph3DConfig,
    planes: np.ndarray | None = None,
    up: np.ndarray | None = None,
    negative: np.ndarray | None = None,
) -> CutResult:
    """Steps 1–4 of the module docstring. ``positive``/``sinks``/``planes``: bool ``[V]``
    (``planes``: the sinks that are supporting surfaces, a subset of ``sinks``); ``up``:
    the scene's up, for :func:`_on_its_support` (None: not applied); ``negative``: bool
    ``[V]``, the negative seeds (a subset of ``sinks``), for :func:`_claimed`."""
    planes = np.zeros(len(graph), bool) if planes is None else planes
    total = 2.0 * float(graph.weights.sum())  # the complement keeps the supports' volume
    # the walk drains into the supports (a post standing on a base loses potential along
    # it); the sweep does not see them (Golovinskiy & Funkhouser remove the ground), so
    # a ball's contact ring with the floor costs nothing
    x, _, deg = walk_potential(graph, positive, sinks | planes, config)
    if planes.any():
        e = graph.edges
        w = np.where(planes[e[:, 0]] | planes[e[:, 1]], 0.0, graph.weights)
        graph = replace(graph, weights=w)
        deg = _laplacian(graph)[1]
    sinks = sinks | planes
    if negative is not None and negative.any() and config.negative_claims:
        sinks = sinks | _claimed(graph, positive, negative, sinks, x, config)
    v = len(graph)
    # positives first, then by potential; sinks last (never in a region)
    key = np.where(positive, 2.0, np.where(sinks | (deg <= 0), -1.0, x))
    order = np.argsort(-key, kind="stable")
    cut = _prefix_cuts(order, graph, deg)
    vol = np.cumsum(deg[order])
    # every positive seed comes with (the better half of) its surroundings, two rings of
    # neighbours: with seeds on two parts (a guitar's fretboard and its headstock) the
    # potential is higher around one of them, and a prefix holding that part and the bare
    # other seed voxel must not count as a region holding both. The better half: a seed
    # on a thin part also touches what lies against it (a stand behind a guitar)
    rank = np.empty(v, np.int64)
    rank[order] = np.arange(v)
    k_min = int(positive.sum())
    for p in np.flatnonzero(positive)[:_MAX_RING_SEEDS]:
        one = np.zeros(v, bool)
        one[p] = True
        near = _rings(graph, one, 2) & (key > 1e-9) & ~positive
        if near.any():
            k_min = max(k_min, int(np.median(rank[near])) + 1)
    k_max = int(np.count_nonzero((~sinks) & ((x > 1e-9) | positive)))
    ks = np.arange(v)
    ok = (ks >= k_min - 1) & (ks < k_max) & (vol > 0)
    # the medium region is no speck: a few voxels of haze around the click are cut off
    # almost for free, yet are not what a click means (the small channel may be one)
    big = ok & (vol >= config.min_region_share * total)
    den = np.minimum(vol, total - vol)
    phi = np.where(ok & (den > 0), cut / np.maximum(den, 1e-300), np.inf)
    if not np.isfinite(phi).any():
        return _degenerate(v, positive, x)
    best = int(np.argmin(np.where(big, phi, np.inf))) if big.any() else int(np.argmin(phi))
    best = _first_tie(phi, vol, big, best, np.minimum(key[order], 1.0), config)
    held_up = best
    if up is not None and config.drop_supports:
        best = _on_its_support(
            graph, order, phi, vol, big, best, k_min, planes, positive, up, config
        )
    minima = _local_minima(phi, vol, config.min_granularity_ratio)
    ratio = config.min_granularity_ratio
    small = _best_where(minima, phi, vol <= vol[best] / ratio, best)
    large = _best_where(minima, phi, vol >= vol[best] * ratio, best)
    rival = [  # specks are no rival: the medium is never one; nor what it stands on
        k
        for k in minima
        if k != best
        and big[k]
        and not (vol[best] / ratio < vol[k] < vol[best] * ratio)
        and (held_up == best or k < best)
        and (k < best or _touches(graph, order, best, k))
    ]
    rival_k = min(rival, key=lambda k: phi[k]) if rival else None
    # φ's at or below clean_phi are all "cut off as well as 0" (their differences are
    # rounding noise): two such regions are equally good
    floor = config.clean_phi
    ambiguous = rival_k is not None and max(phi[rival_k], floor) <= config.ambiguity_ratio * max(
        phi[best], floor
    )
    levels = []
    for k in (small, best, large):
        nodes = np.zeros(v, bool)
        nodes[order[: k + 1]] = True
        neck = _narrowness(graph, nodes, planes, config.neck_min_voxels)
        c = _contrast(graph, nodes, planes) * min(1.0, neck)
        s = 1.0 / (1.0 + (c / config.score_contrast) ** 2)
        s *= 1.0 - min(1.0, _rim_cut(graph, nodes) / max(float(cut[k]), 1e-300))
        if ambiguous:
            s *= config.ambiguity_penalty
        levels.append(Granularity(nodes, float(phi[k]), float(s), float(vol[k]), c))
    share = _rim_cut(graph, levels[1].nodes) / max(float(cut[best]), 1e-300)
    alt = None if rival_k is None else float(vol[rival_k] / max(vol[best], 1e-300))
    return CutResult(tuple(levels), x, float(min(share, 1.0)), bool(ambiguous), alt)


def _touches(graph: VoxelGraph, order: np.ndarray, best: int, k: int) -> bool:
    """Whether what the prefix ``k`` adds to the prefix ``best`` (``k > best``) touches
    it (an edge of nonzero affinity between them): a larger region that only adds a
    separate piece (an object beside the clicked one, joined through the removed floor)
    is another object, not another reading of the clicked one."""
    inside = np.zeros(len(graph), bool)
    inside[order[: best + 1]] = True
    added = np.zeros(len(graph), bool)
    added[order[best + 1 : k + 1]] = True
    e = graph.edges
    cross = (inside[e[:, 0]] & added[e[:, 1]]) | (added[e[:, 0]] & inside[e[:, 1]])
    return bool(np.any(graph.weights[cross] > 0.0))


def _claimed(
    graph: VoxelGraph,
    positive: np.ndarray,
    negative: np.ndarray,
    sinks: np.ndarray,
    x: np.ndarray,
    config: Graph3DConfig,
) -> np.ndarray:
    """Bool ``[V]``: the voxels a walk reaches a negative seed from before a positive one
    (Grady's random walker with two labels: the walk from the negative seeds ``y``, the
    positive ones and the other sinks draining, against the positive walk ``x``;
    ``y > x``): what the negative click is on. A negative seed is one sink voxel in the
    positive walk — an island it lies on (a pedestal the statue stands on) keeps
    conductance 0 without it, and the click would change nothing; its part then leaves
    the sweep like a sink."""
    other = (sinks & ~negative) | positive
    y, _, _ = walk_potential(graph, negative, other, config)
    return (y > x) & ~positive


def _rings(graph: VoxelGraph, nodes: np.ndarray, n: int) -> np.ndarray:
    """``nodes`` and their neighbours up to ``n`` edges away (bool ``[V]``)."""
    e = graph.edges
    out = nodes.copy()
    for _ in range(n):
        grow = out.copy()
        grow[e[out[e[:, 0]], 1]] = True
        grow[e[out[e[:, 1]], 0]] = True
        out = grow
    return out


def _contrast(graph: VoxelGraph, nodes: np.ndarray, planes: np.ndarray) -> float:
    """Mean affinity of the region's cut edges (those to a supporting plane left out:
    the plane's sinks are set, not found) over the mean affinity inside it; 0 when
    nothing is cut but planes and the rim."""
    e, w = graph.edges, graph.weights
    a, b = nodes[e[:, 0]], nodes[e[:, 1]]
    inside = a & b
    other = np.where(a, e[:, 1], e[:, 0])
    cut = (a ^ b) & ~planes[other] & ~graph.rim[other]
    if not cut.any() or not inside.any():
        return 0.0
    return float(np.mean(w[cut]) / max(float(np.mean(w[inside])), 1e-300))


def _narrowness(
    graph: VoxelGraph, nodes: np.ndarray, planes: np.ndarray, min_ring: int = 0
) -> float:
    """Boundary voxels of the region (those with a cut edge, supporting planes left out) over
    the perimeter of a disc of as many voxels, ``2 sqrt(π n)``: 1 for a patch cut out of a
    continuing surface, well below 1 at a neck (a head on its shoulders, a pot's handle),
    whose cut is a real boundary even where the affinities across it stay high — the
    smallest being a contact: an object leaning on another touches it in a few voxels. A
    boundary of fewer than ``min_ring`` voxels counts as none (1; the default 0 counts
    every one, :class:`~.config.Graph3DConfig`)."""
    e = graph.edges
    a, b = nodes[e[:, 0]], nodes[e[:, 1]]
    other = np.where(a, e[:, 1], e[:, 0])
    inner = np.where(a, e[:, 0], e[:, 1])
    cut = (a ^ b) & ~planes[other]  # a region running into the rim goes on: no neck there
    n = int(np.count_nonzero(nodes))
    ring = len(np.unique(inner[cut]))
    if n == 0 or ring < min_ring:
        return 1.0
    return float(ring / (2.0 * np.sqrt(np.pi * n)))


def _rim_cut(graph: VoxelGraph, nodes: np.ndarray) -> float:
    e, w = graph.edges, graph.weights
    a, b = nodes[e[:, 0]], nodes[e[:, 1]]
    to_rim = (a & graph.rim[e[:, 1]]) | (b & graph.rim[e[:, 0]])
    return float(w[to_rim].sum())


def _local_minima(phi: np.ndarray, vol: np.ndarray, ratio: float) -> list[int]:
    """Prefix sizes whose φ is the least within ± ``ratio`` of their volume."""
    fin = np.isfinite(phi)
    if not fin.any():
        return []
    lv = np.log(np.maximum(vol, 1e-300))
    lo, hi = lv[fin].min(), lv[fin].max()
    if hi - lo < 1e-9:
        return [int(np.argmin(phi))]
    b = np.clip(((lv - lo) / (hi - lo) * (_LOG_BINS - 1)).astype(np.int64), 0, _LOG_BINS - 1)
    best_phi = np.full(_LOG_BINS, np.inf)
    best_k = np.full(_LOG_BINS, -1)
    ks = np.flatnonzero(fin)[np.argsort(-phi[fin])]  # per bin the last of these: least φ
    bins, last = np.unique(b[ks][::-1], return_index=True)
    best_k[bins] = ks[::-1][last]
    best_phi[bins] = phi[best_k[bins]]
    width = max(1, int(round(np.log(ratio) / (hi - lo) * (_LOG_BINS - 1))))
    filt = minimum_filter1d(best_phi, size=2 * width + 1, mode="nearest")
    return [int(best_k[i]) for i in range(_LOG_BINS) if best_k[i] >= 0 and best_phi[i] <= filt[i]]


def _first_tie(
    phi: np.ndarray,
    vol: np.ndarray,
    big: np.ndarray,
    best: int,
    xs: np.ndarray,
    config: Graph3DConfig,
) -> int:
    """The smallest region as good as the least-φ one and not left by the walk: a dip
    of φ (the least within ± ``tie_window`` of its volume) at a smaller volume whose φ
    is within ``ambiguity_ratio`` of the best (or below ``clean_phi``: both cut off)
    and beyond which the sweep runs on only through voxels the walk hardly reaches
    (median potential below ``tie_potential`` × the dip region's median; ``xs``: the
    potential in sweep order). Past an object's clean boundary the sweep may run on
    through a piece that hangs on it as weakly as on everything else (an occluder
    touching it in a few voxels): that piece costs no cut, so the larger prefix is as
    good by conductance, and only the walk says it is not the object's. Along a rod
    the conductance falls steadily to its end, with no dip on the way: kept whole."""
    if not np.isfinite(phi[best]):
        return best
    tol = config.ambiguity_ratio * max(float(phi[best]), 0.0) + config.clean_phi
    dips = _local_minima(np.where(big, phi, np.inf), vol, config.tie_window)
    for k in sorted((k for k in dips if k < best and phi[k] <= tol), key=lambda k: vol[k]):
        if np.median(xs[k + 1 : best + 1]) < config.tie_potential * np.median(xs[: k + 1]):
            return k
    return best


def _on_its_support(
    graph: VoxelGraph,
    order: np.ndarray,
    phi: np.ndarray,
    vol: np.ndarray,
    big: np.ndarray,
    best: int,
    k_min: int,
    planes: np.ndarray,
    positive: np.ndarray,
    up: np.ndarray,
    config: Graph3DConfig,
) -> int:
    """The region that stands on what the chosen one adds beyond it, repeated while one
    does (a statue on its pedestal on a plinth): the largest dip of φ
    (:func:`_local_minima` over ± ``tie_window``) smaller than the chosen region that
    holds every seed and has a clear boundary (contrast below ``score_contrast``, where
    the score is ½), whose added part ``E`` (no seed in it) is another material
    (:func:`~.voxel_graph.other_material`), lies below the boundary (all but
    ``support_quantile`` of it no higher than the boundary's highest voxel plus one
    voxel; as many of the dip's voxels no lower than its lowest minus one, and as many
    higher than that voxel plus two: what stands rises above its contact — a patch whose
    boundary runs around its sides, level with it, is set in E, not on it) and is wider
    there than what stands on it (the horizontal spread of the top two voxels of all
    the dip stands on — E and the layers peeled before it, within the least-φ region —
    over that of the dip's bottom two). What holds the clicked object up — a pedestal of
    another material, a plinth, a table's frame — is not the object, though it makes
    one island with it once the floor is removed (conductance 0: it would always win
    the sweep). A click on the support (a seed below the contact) keeps it. The upper half
    of a statue stands on its lower half of the same material, a flower's head on a
    narrower stem: kept whole. The foliage standing on its pot is cut the same way when
    the click is above the contact; a click on the pot keeps both."""
    height = graph.centroid @ np.asarray(up, np.float64)
    flat = graph.centroid - height[:, None] * np.asarray(up, np.float64)[None, :]
    e = graph.edges
    q, h = config.support_quantile, graph.h
    dips = _local_minima(np.where(big, phi, np.inf), vol, config.tie_window)
    whole = best  # the least-φ region: what the dips stand on is measured within it
    changed = True
    while changed:
        changed = False
        for k in sorted((k for k in dips if k_min - 1 <= k < best), key=lambda k: -vol[k]):
            inside = np.zeros(len(graph), bool)
            inside[order[: k + 1]] = True
            extra = np.zeros(len(graph), bool)
            extra[order[k + 1 : best + 1]] = True
            a, b = inside[e[:, 0]], inside[e[:, 1]]
            cross = (a & extra[e[:, 1]]) | (b & extra[e[:, 0]])
            if not cross.any() or _contrast(graph, inside, planes) > config.score_contrast:
                continue
            if not other_material(graph.lab[extra], graph.lab[inside]):
                continue
            ring = np.unique(e[cross].ravel())  # the voxels on both sides of the boundary
            top, bottom = float(height[ring].max()), float(height[ring].min())
            if np.quantile(height[extra], 1.0 - q) > top + h:
                continue  # E reaches above the contact: it does not hold the dip up
            if np.quantile(height[inside], q) < bottom - h:
                continue  # the dip reaches below the contact: it does not stand on E
            if np.quantile(height[inside], 1.0 - q) <= top + 2.0 * h:
                continue  # the dip does not rise above the contact: E is around it
            if float(height[positive].min()) < bottom - h:
                break  # a click below the contact, on E: the user wants it too
            # the width of all it stands on (peeled off in layers, the last one a rim
            # around its foot as wide as the foot itself; a stem is narrower)
            below = np.zeros(len(graph), bool)
            below[order[k + 1 : whole + 1]] = True
            e_top = below & (height >= float(height[below].max()) - 2.0 * h)
            d_bottom = inside & (height <= float(height[inside].min()) + 2.0 * h)
            if _spread(flat[e_top]) <= _spread(flat[d_bottom]):
                continue  # E is narrower than what stands on it: a stem, a leg
            best, changed = k, True
            break
    return best


def _spread(points: np.ndarray) -> float:
    """RMS distance of points from their mean (0 for none)."""
    if len(points) == 0:
        return 0.0
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def _best_where(minima: list[int], phi: np.ndarray, allowed: np.ndarray, fallback: int) -> int:
    cand = [k for k in minima if allowed[k]]
    return min(cand, key=lambda k: phi[k]) if cand else fallback


def _degenerate(v: int, positive: np.ndarray, x: np.ndarray) -> CutResult:
    nodes = positive.copy()
    g = Granularity(nodes, float("inf"), 0.0, 0.0)
    return CutResult((g, g, g), x, 0.0, True, None)

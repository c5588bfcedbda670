"""The weight-free default segmenter: a 3D cut over the scene's own primitives, rendered
into each view as its mask (beyond the paper, which takes SAM's masks).

Per prompt set on a view (:meth:`Graph3DSegmenter.predict`): the prompts and the
object's 3D clicks on every anchor become seeds; the active voxels around the positive
seeds form a local graph (:mod:`.voxel_graph`); a random walk and sweep cut give three
nested regions and a score (:mod:`.cut`), the region grown when it leans on its rim;
the regions are rendered into the view as per-primitive coverage at SAM's low-res size,
so every view shows the same 3D region and the preview is what fusion certifies. Cuts
are cached per seed set and can be prefetched from the 3D clicks before the view
renders (:mod:`.cut_cache`). The steps in full: ``docs/design-notes.md``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from ...camera import Camera
from ...scene import SurfelScene
from ..base import SegResult, as_depth, as_prompts
from ..context import ObjectClicks, SceneBinding, ViewContext
from ..sam_common import sigmoid
from ..scene_aware import SceneAwareSegmenter
from .config import Graph3DConfig
from .cut import CutResult, sweep_cut
from .cut_cache import CutCache
from .primitives import ScenePrimitives
from .render_box import WHOLE, screen_box
from .supports import support_nodes, support_primitives
from .voxel_graph import VoxelGraph, build_voxel_graph

__all__ = ["Graph3DSegmenter", "RegionCut", "Seeds", "advice", "seed_nodes"]

#: the hint when a positive click hits nothing (the add-on's plain-language table knows it)
NO_SURFACE = "no surface under the click: click on the object itself"

_CUT_CACHE = 16  # a state's cut, its joint cut and the cuts before its newest clicks
_MASK_CACHE = 2  # masks rendered ahead are taken once: 3 × H × W floats each
_SAME_CLICK_PX = 2.0
_VIEW_CUTS_KEPT = 8  # views whose rendered selections are kept (rendered_selection)
#: the mask render's window margin, pixels: the renderer's screen-space low-pass disc
#: (σ √2/2 px, cut off at 3.33 σ = 2.4 px) and rounding
_MASK_MARGIN_PX = 4.0


@dataclass(frozen=True, eq=False)
class Seeds:
    """3D seed points: ``positive [P,3]``, ``negative [Q,3]``; ``history [H,3]``: the
    object's positive 3D clicks among them in click order, when there are two or more
    (None otherwise): the cut keeps what the cuts of the seeds before its newest clicks
    held (:meth:`Graph3DSegmenter.cut`, ``kept_clicks``)."""

    positive: np.ndarray
    negative: np.ndarray
    history: np.ndarray | None = None

    def key(self) -> bytes:
        k = np.round(self.positive, 6).tobytes() + b"|" + np.round(self.negative, 6).tobytes()
        return k if self.history is None else k + b"|+" + self.history.tobytes()

    def joint(self) -> Seeds:
        """The same seeds without their click order: one cut of them all."""
        return Seeds(self.positive, self.negative)

    def before(self, clicks: int) -> Seeds | None:
        """The seeds as they were before the newest ``clicks`` positive clicks, without
        their order (None when no positive click would be left)."""
        if clicks >= len(self.history):
            return None
        drop = self.history[len(self.history) - clicks :]
        keep = ~np.any(np.all(self.positive[:, None, :] == drop[None], axis=2), axis=1)
        return Seeds(self.positive[keep], self.negative)


@dataclass(eq=False)
class RegionCut:
    """One cut in 3D: the three nested primitive selections and how they were found.

    Attributes:
        selected: ``[3, M]`` bool over :class:`ScenePrimitives` (small, medium, large).
        scores: ``[3]``; message: advice when the medium score is low, else None.
        cut: the :class:`~.cut.CutResult`; graph: its :class:`~.voxel_graph.VoxelGraph`.
        radius: the region radius R used; grows: how often R was enlarged.
        seconds: time of the cut (graph + walk + sweep).
    """

    selected: np.ndarray
    scores: np.ndarray
    message: str | None
    cut: CutResult | None
    graph: VoxelGraph | None
    radius: float
    grows: int
    seconds: float = 0.0
    info: dict = field(default_factory=dict)


class Graph3DSegmenter(SceneAwareSegmenter):
    """3D graph-cut segmenter over the scene's primitives (module docstring).

    Args:
        config: :class:`Graph3DConfig`.
        binding: optional :class:`~..scene_aware.SceneBinding` (else the session binds).
    """

    name = "graph3d"
    #: render the masks only in the window the selection can reach (:mod:`.render_box`),
    #: with only the surfels in front of it; False: the dense render of the whole image
    #: (the reference the tests compare with)
    fast_masks: bool = True
    #: :meth:`prefetch` starts the cut in a background thread (False: it does nothing).
    #: It trades a later view for an earlier mask: on few cores the cut competes with the
    #: view's render, so it pays only where the caller previews right after the click —
    #: the add-on switches it on (its click operator returns view and mask together)
    prefetch_cuts: bool = False
    #: with :attr:`prefetch_cuts`, :meth:`prefetch_view` also renders the masks of the
    #: view's default prompt in the background once the view's camera is known (the
    #: session calls it before the view renders): the mask render then runs beside the
    #: view's render instead of after it; on few cores it fills the render's serial
    #: phases (the work is CPU-bound). The masks are the same bits (the same function of
    #: the seeds and the camera; a split is per item, so one launch thread gives the same
    #: image)
    prefetch_masks: bool = True
    #: :meth:`warm_up` also computes every primitive's colour (and κ) once
    #: (:meth:`ScenePrimitives.cache_features`: the scene-only part of each cut, ≈ 0.08 s
    #: of a click's cut; 12 bytes a primitive held); the cuts are the same bit for bit
    #: with and without it
    cache_features: bool = True
    #: every view shows the same 3D cut, scored once: an unsure cut is fused with its
    #: advice, not refused (:attr:`~..base.Segmenter.score_gates_views`)
    score_gates_views: bool = False

    def __init__(self, config: Graph3DConfig | None = None, binding: SceneBinding | None = None):
        super().__init__(cache_size=16)
        self.config = config or Graph3DConfig()
        self.prims: ScenePrimitives | None = None
        self.last_message: str | None = None
        self.last_cut: RegionCut | None = None
        #: per view id: the ``[3, M]`` selections its last masks rendered (the cut's own
        #: arrays), the newest ``_VIEW_CUTS_KEPT`` views (:meth:`rendered_selection`)
        self.view_cuts: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self.cuts: CutCache[RegionCut] = CutCache(_CUT_CACHE)
        #: masks of a default prompt by (seeds, camera), rendered ahead (prefetch_view)
        self.masks: CutCache[np.ndarray] = CutCache(_MASK_CACHE)
        self._prims_lock = threading.Lock()
        if binding is not None:
            self.bind_scene(binding)

    # ------------------------------------------------------------------ binding
    def _on_bind(self, binding: SceneBinding) -> None:
        self.prims = None  # built on first use (the session opens without waiting)
        self.cuts.clear()
        self.masks.clear()
        self.view_cuts.clear()  # another scene's selections (the same view ids recur)

    def warm_up(self) -> None:
        """Build the scene's :class:`ScenePrimitives` now (the session's background
        warm-up), so that the first click does not wait seconds for them. A prompt
        made meanwhile waits for the same build (one lock), never builds twice. Then,
        with :attr:`cache_features`, every primitive's colour / κ (the cut's scene-only
        work; a prompt made meanwhile computes its own rows)."""
        with contextlib.suppress(Exception):  # the first prompt builds again and raises
            prims = self.primitives()
            if self.cache_features:
                # prompts meanwhile compute their rows' features (the same values)
                prims.cache_features()

    def primitives(self) -> ScenePrimitives:
        """The bound scene's :class:`ScenePrimitives` (built once)."""
        if self.binding is None:
            raise RuntimeError(f"{self.name}: bind_scene() first (the session does it)")
        with self._prims_lock:
            if self.prims is None:
                up = None if self.binding.up is None else self.binding.up()
                self.prims = ScenePrimitives.from_scene(
                    self.binding.scene, self.config.min_opacity, up
                )
            return self.prims

    @property
    def prefetches(self) -> bool:
        return self.prefetch_cuts

    def wait_prefetch(self, timeout: float | None = None) -> bool:
        """Wait for the cuts and masks :meth:`prefetch` / :meth:`prefetch_view` started (a
        closing session: no thread may outlive it, e.g. into Blender's exit); whether all
        ended within ``timeout``."""
        return self.masks.wait(timeout) and self.cuts.wait(timeout)

    def prefetch(self, clicks: ObjectClicks) -> bool:
        """Start, in a background thread, the cut a prompt of the default prompts on any
        view of the object with these 3D ``clicks`` will use (:meth:`seeds` maps each
        default prompt back to its click, so those seeds are :meth:`seeds_of` the
        clicks): the session calls it as soon as a click's 3D point is known, and the
        view renders meanwhile. The prompt then takes the same
        :class:`RegionCut` from the cache, or waits for it (:mod:`.cut_cache`). Whether
        a cut was started (not when it is kept or running already, or there is no
        positive click)."""
        seeds = self.seeds_of(clicks)
        if not self.prefetch_cuts or self.binding is None or len(seeds.positive) == 0:
            return False
        return self.cuts.start(seeds.key(), lambda: self._compute(seeds))

    def prefetch_view(self, camera: Camera, clicks: ObjectClicks) -> bool:
        """Start, in a background thread, the masks a prompt of the default prompts on
        the view with ``camera`` will return (the object's 3D ``clicks`` as seeds:
        :meth:`prefetch`), rendered with one launch thread beside the view's own render
        The prompt takes them (:meth:`_predict`), or waits for them; they are
        what it would render (the same seeds' cut, the same camera). Whether a render
        was started (:attr:`prefetch_cuts` and :attr:`prefetch_masks` on, a positive
        click, not kept or running already)."""
        seeds = self.seeds_of(clicks)
        if not (self.prefetch_cuts and self.prefetch_masks) or self.binding is None:
            return False
        if len(seeds.positive) == 0:
            return False
        return self.masks.start(
            _masks_key(seeds, camera),
            lambda: self.render_masks(camera, self.cut(seeds).selected, threads=1),
        )

    @staticmethod
    def seeds_of(clicks: ObjectClicks) -> Seeds:
        """The seeds of an object's 3D clicks alone (what :meth:`seeds` gives for
        prompts that are all known clicks)."""
        pts = np.asarray(clicks.points)
        pos = np.asarray(clicks.positive, bool)
        seeds = _seeds([pts[pos]] if len(pts) else [], [pts[~pos]] if len(pts) else [])
        return _with_history(seeds, clicks)

    # ------------------------------------------------------------------ Segmenter hooks
    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id) -> Any:
        raise ValueError(f"{self.name}: segments a view of its scene: call segment_view")

    def segment_view(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> SegResult:
        """Masks and scores of a prompt set on ``view`` (its camera, depth and the
        object's 3D clicks; module docstring); ``message``: the advice of a low score."""
        if self.binding is None:
            raise RuntimeError(f"{self.name}: bind_scene() first (the session does it)")
        cam = view.camera
        if cam is None:
            raise ValueError(f"{self.name}: needs the camera of view {view.id!r}")
        hw = np.shape(view.rgb)[:2]
        if (cam.height, cam.width) != hw:
            raise ValueError(
                f"{self.name}: view {view.id!r} camera is {cam.width}x{cam.height}, "
                f"the image {hw[1]}x{hw[0]}"
            )
        p, lab = as_prompts(points, labels)
        view = replace(view, depth=as_depth(view.depth, hw))
        with self._lock:
            masks, scores = self._predict(view, p, lab)
            return SegResult(masks, scores.astype(np.float32), self.last_message)

    def _predict(
        self, view: ViewContext, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        seeds, missed = self.seeds(view, points, labels)
        h, w = view.camera.height, view.camera.width
        if len(seeds.positive) == 0:
            self.last_message = NO_SURFACE if missed else None
            return np.zeros((3, h, w), np.float32), np.zeros(3, np.float32)
        rc = self.cut(seeds)
        self.last_cut, self.last_message = rc, rc.message
        self.view_cuts[view.id] = rc.selected
        self.view_cuts.move_to_end(view.id)
        while len(self.view_cuts) > _VIEW_CUTS_KEPT:
            self.view_cuts.popitem(last=False)
        key = _masks_key(seeds, view.camera)
        if self.masks.peek(key) is None and self.masks.in_flight(key) is None:
            masks = self.render_masks(view.camera, rc.selected)
        else:  # rendered ahead (prefetch_view) or rendering: a copy of the kept ones
            masks = self.masks.get(key, lambda: self.render_masks(view.camera, rc.selected))
            masks = masks.copy()
        return masks, rc.scores.astype(np.float32)

    def rendered_selection(
        self, view_id: Hashable, channel: int = 1
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """``([n,3] centres, [n] opacities)`` of the primitives of the 3D selection of
        ``channel`` that the last masks of ``view_id`` rendered; None for a view not
        segmented lately."""
        with self._lock:
            selected = self.view_cuts.get(view_id)
        if selected is None:
            return None
        prims = self.primitives()
        rows = np.flatnonzero(selected[channel])
        return np.asarray(prims.points[rows], np.float64), np.asarray(prims.mass[rows], np.float64)

    # ------------------------------------------------------------------ steps
    def seeds(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> tuple[Seeds, int]:
        """Step 1: the 3D seeds of a prompt set on a view (and how many prompt points
        had no surface under them). A prompt point within ``_SAME_CLICK_PX`` of a known 3D
        click's projection is that click (the session's default prompt is the click's
        point projected): its exact 3D point is used, not the view's depth there, which
        at a silhouette or behind a floater can be another surface."""
        pos, neg, missed = [], [], 0
        oc = view.clicks
        if len(points) and len(oc.points):
            uv, zc = view.camera.project(np.asarray(oc.points, np.float64))
            d = np.linalg.norm(points[:, None, :] - uv[None], axis=2)
            known = np.any((d <= _SAME_CLICK_PX) & (zc[None] > 0), axis=1)
            points, labels = points[~known], labels[~known]
        if len(points) and view.depth is not None:
            hgt, wid = view.depth.shape
            cols = np.clip(np.floor(points[:, 0]).astype(np.int64), 0, wid - 1)
            rows = np.clip(np.floor(points[:, 1]).astype(np.int64), 0, hgt - 1)
            z = view.depth[rows, cols]
            ok = np.isfinite(z) & (z > 0)
            missed = int(np.count_nonzero(~ok & (labels == 1)))
            if ok.any():
                xyz = view.camera.unproject(points[ok], z[ok].astype(np.float64))
                lab = labels[ok]
                pos.append(xyz[lab == 1])
                neg.append(xyz[lab == 0])
        if len(oc.points):
            pos.append(np.asarray(oc.points)[oc.positive])
            neg.append(np.asarray(oc.points)[~oc.positive])
        return _with_history(_seeds(pos, neg), oc), missed

    def cut(self, seeds: Seeds) -> RegionCut:
        """Steps 2–3 (cached per seed set; a cut :meth:`prefetch` started is waited
        for): the three nested 3D selections."""
        return self.cuts.get(seeds.key(), lambda: self._compute(seeds))

    def _compute(self, seeds: Seeds) -> RegionCut:
        """The cut of ``seeds``; with a click order, each of its three selections also
        keeps what the cuts of the seeds before each of the newest ``kept_clicks``
        positive clicks held (each with every negative click). A positive click says
        "this too": it does not take away what the object's cut held (the sweep can
        otherwise settle on a tighter boundary once another seed moves the walk's level
        sets); negative clicks are in every cut, so they still remove. Beyond the paper
        (its SAM masks have no such rule). The cuts before are kept in the cache, so a
        positive click costs one cut; a negative one ``kept_clicks + 1``."""
        if seeds.history is None:
            return self._cut(seeds)
        olders = [seeds.before(k) for k in range(1, self.config.kept_clicks + 1)]
        olders = [o for o in olders if o is not None]
        for o in olders:  # the cuts not kept run beside the joint one (a negative click)
            self.cuts.start(o.key(), lambda o=o: self._cut(o))
        joint = self.cut(seeds.joint())
        if joint.cut is None:
            return joint
        selected = joint.selected.copy()
        for o in olders:
            rc = self.cut(o)
            if rc.cut is not None:
                selected |= rc.selected
        return replace(joint, selected=selected)

    def _cut(self, seeds: Seeds) -> RegionCut:
        t0 = time.perf_counter()
        cfg = self.config
        prims = self.primitives()
        centre = 0.5 * (seeds.positive.min(axis=0) + seeds.positive.max(axis=0))
        spread = float(np.linalg.norm(seeds.positive - centre, axis=1).max())
        radius = max(cfg.region_min * prims.radius, cfg.region_seed_factor * spread)
        grows = 0
        band = cfg.ground_band * prims.radius
        on_ground = any(
            bool(np.any(np.abs(g.height(seeds.positive)) <= band)) for g in prims.grounds
        )
        while True:
            graph = build_voxel_graph(prims, centre, radius, cfg)
            pos = np.zeros(len(graph), bool)
            pn = seed_nodes(graph, prims, seeds.positive)
            pos[pn[pn >= 0]] = True
            if not pos.any():
                return self._empty(prims, NO_SURFACE, radius, grows, t0)
            neg = np.zeros(len(graph), bool)
            nn = seed_nodes(graph, prims, seeds.negative)
            neg[nn[nn >= 0]] = True
            sinks = graph.rim | neg
            planes = support_nodes(graph, prims, pos, cfg, neg) & ~pos
            sinks = (sinks | planes) & ~pos
            res = sweep_cut(graph, pos, sinks, cfg, planes, prims.up, neg & ~pos)
            if _too_small(res, graph, cfg, on_ground) and grows < cfg.region_max_grows:
                radius *= cfg.region_grow
                grows += 1
                continue
            break
        sel = np.zeros((3, len(prims)), bool)
        on_support = support_primitives(graph, prims, planes, cfg)
        graph.up_height = graph.up_dot = None  # read once: not kept in the cut cache
        for k, lev in enumerate(res.levels):
            sel[k, graph.prim] = lev.nodes[graph.voxel_of] & ~on_support
        scores = np.array([lev.score for lev in res.levels], np.float32)
        msg = self._advice(res, scores[1], len(seeds.negative))
        return RegionCut(
            sel,
            scores,
            msg,
            res,
            graph,
            radius,
            grows,
            time.perf_counter() - t0,
            {"voxels": len(graph), "edges": len(graph.edges), "h": graph.h},
        )

    def _empty(self, prims, msg, radius, grows, t0) -> RegionCut:
        sel = np.zeros((3, len(prims)), bool)
        return RegionCut(
            sel, np.zeros(3, np.float32), msg, None, None, radius, grows, time.perf_counter() - t0
        )

    def _advice(self, res: CutResult, score: float, n_negative: int) -> str | None:
        return advice(res, score, n_negative, self.config.rim_share)

    def render_masks(
        self, camera: Camera, selected: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """Step 4: ``[3,H,W]`` probabilities of three primitive selections in ``camera``
        (``threads``: the sparse render's CPU launch threads; None: the renderer's)."""
        cfg = self.config
        h, w = camera.height, camera.width
        s = min(1.0, cfg.low_res / max(h, w))
        cam = camera if s == 1.0 else camera.scaled(s)
        cov = self._coverage(cam, selected, threads)
        logits = np.float32(cfg.logit_scale) * (cov - np.float32(0.5))
        if (cam.height, cam.width) != (h, w):
            logits = cv2.resize(logits, (w, h), interpolation=cv2.INTER_LINEAR)
        return np.ascontiguousarray(sigmoid(logits).transpose(2, 0, 1), dtype=np.float32)

    def _coverage(
        self, cam: Camera, selected: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """``[H,W,3]`` coverage of the selections in ``cam``: rendered in the window their
        footprints can reach (:mod:`.render_box`), 0 elsewhere, with only the surfels
        that can blend before them when the binding offers that render
        (:attr:`~..scene_aware.SceneBinding.render_sparse`) — the whole image, densely,
        when the window's border shows coverage (a renderer whose footprints reach
        farther) or when :attr:`fast_masks` is off."""
        prims = self.primitives()
        cov = np.zeros((cam.height, cam.width, 3), np.float32)
        cols = np.flatnonzero(selected.any(axis=0))
        box = WHOLE
        if self.fast_masks:
            box = screen_box(cam, prims.points[cols], prims.reach_of(cols), _MASK_MARGIN_PX)
        if box is None:
            return cov
        x0, y0, x1, y1 = (0, 0, cam.width, cam.height) if box == WHOLE else box
        sub = cam if box == WHOLE else cam.cropped(x0, y0, x1 - x0, y1 - y0)
        sparse = self.binding.render_sparse if self.fast_masks else None
        if sparse is not None and isinstance(prims.scene, SurfelScene):
            vals = selected[:, cols].T.astype(np.float32)
            kw = {} if threads is None else {"threads": threads}
            part = np.asarray(sparse(sub, prims.rows_of(cols), vals, **kw), np.float32)
        else:
            vals = prims.render_array(selected.T.astype(np.float32))
            part = np.asarray(self.binding.render_values(sub, vals), np.float32)
        cov[y0:y1, x0:x1] = part.reshape(y1 - y0, x1 - x0, 3)
        if box != WHOLE and _border_shows(cov, (x0, y0, x1, y1)):
            vals = prims.render_array(selected.T.astype(np.float32))
            full = self.binding.render_values(cam, vals)
            cov = np.asarray(full, np.float32).reshape(cam.height, cam.width, 3)
        return cov


def seed_nodes(graph: VoxelGraph, prims: ScenePrimitives, points: np.ndarray) -> np.ndarray:
    """The graph node of each seed point: :meth:`VoxelGraph.node_of_points` (the voxel
    holding it, or a node centroid within two voxels), else the voxel of the primitive
    whose footprint holds the point — the one nearest in units of its reach (its
    4 σ cutoff), among those that reach it; ``-1`` when none does. A click's 3D point
    is where the rendered surface is (the depth tuple's estimate): on a trained 3DGS
    scene that surface lies a σ or two in front of the centres of the Gaussians that
    draw it, farther than two voxels when the Gaussians are large."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    out = graph.node_of_points(pts)
    miss = np.flatnonzero(out < 0)
    if len(miss) == 0 or len(graph.prim) == 0:
        return out
    centres = np.asarray(prims.points[graph.prim], np.float64)
    reach = np.maximum(np.asarray(prims.reach_of(graph.prim), np.float64), 1e-12)
    for i in miss:
        r = np.linalg.norm(centres - pts[i], axis=1) / reach
        j = int(np.argmin(r))
        if r[j] <= 1.0:
            out[i] = int(graph.voxel_of[j])
    return out


def _masks_key(seeds: Seeds, camera: Camera) -> bytes:
    """What a default prompt's masks depend on beyond the scene: the seeds and the camera."""
    c = camera
    intr = np.array([c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.near], np.float64)
    return seeds.key() + b"|" + np.asarray(c.c2w, np.float64).tobytes() + intr.tobytes()


def _with_history(seeds: Seeds, clicks: ObjectClicks) -> Seeds:
    """``seeds`` with the click order of the object's positive 3D clicks among them
    (:class:`Seeds`; repeated points count once, at their first click), when two or more."""
    pts = np.asarray(clicks.points, np.float64).reshape(-1, 3)
    pos = np.round(pts[np.asarray(clicks.positive, bool)], 6)
    if len(pos) < 2:
        return seeds
    _, first = np.unique(pos, axis=0, return_index=True)
    order = pos[np.sort(first)]
    held = (order[:, None, :] == seeds.positive[None]).all(axis=2).any(axis=1)
    order = order[held]
    return seeds if len(order) < 2 else Seeds(seeds.positive, seeds.negative, order)


def _seeds(pos: list[np.ndarray], neg: list[np.ndarray]) -> Seeds:
    """The :class:`Seeds` of positive and negative 3D point sets: rounded to 1e-6, unique
    (sorted), so equal point sets in any order give one key."""
    p = np.concatenate(pos) if pos else np.zeros((0, 3))
    q = np.concatenate(neg) if neg else np.zeros((0, 3))
    p = np.unique(np.round(p.reshape(-1, 3), 6), axis=0)
    q = np.unique(np.round(q.reshape(-1, 3), 6), axis=0)
    return Seeds(p, q)


def _border_shows(cov: np.ndarray, box: tuple[int, int, int, int]) -> bool:
    """Any coverage on the window's border rows/columns that are not the image's own."""
    x0, y0, x1, y1 = box
    h, w = cov.shape[:2]
    edges = []
    if x0 > 0:
        edges.append(cov[y0:y1, x0])
    if x1 < w:
        edges.append(cov[y0:y1, x1 - 1])
    if y0 > 0:
        edges.append(cov[y0, x0:x1])
    if y1 < h:
        edges.append(cov[y1 - 1, x0:x1])
    return any(bool(np.any(e != 0.0)) for e in edges)


def _too_small(res: CutResult, graph: VoxelGraph, cfg: Graph3DConfig, on_ground: bool) -> bool:
    """The region looked at is too small for the object: its cut leans on the rim, or no
    clear boundary was found inside it — or the chosen region holds more than half of
    the graph's volume — while the walk still reaches the rim (a click near one end of
    an object about as large as the region: the cut then crosses the object where the
    region's outside drains it) — unless the click is on the ground, which goes on
    anyway."""
    if res.rim_share > cfg.rim_share:
        return True
    if on_ground:
        return False
    # the region holds most of what was looked at: its conductance was measured against
    # the little left over (a guitar's neck filling a box that stops above the body)
    total = 2.0 * float(graph.weights.sum())  # the graph's volume, Σ deg
    most = res.levels[1].volume > 0.5 * total
    if res.levels[1].score >= 0.5 and not most:
        return False
    e = graph.edges
    rim_a, rim_b = graph.rim[e[:, 0]], graph.rim[e[:, 1]]
    x_by_rim = np.r_[res.potential[e[rim_a & ~rim_b, 1]], res.potential[e[rim_b & ~rim_a, 0]]]
    return len(x_by_rim) > 0 and float(x_by_rim.max()) > cfg.rim_reach


def advice(res: CutResult, score: float, n_negative: int, rim_share: float) -> str | None:
    """What the user should do when the cut is unsure (medium ``score`` < 0.5), in plain
    words: why it is unsure, then the click that settles it — a click on what is missing
    (the object goes on past the examined region, or the click fits a part of a larger
    whole) or a negative click on what spilled over (no clear edge, or a larger region
    fits too). None when the cut is sure."""
    if score >= 0.5:
        return None
    if res.rim_share > rim_share:
        return (
            "The object seems to go on past the area looked at around your click: add a "
            "click on its far end"
        )
    if res.ambiguous and res.alternative is not None and res.alternative > 1.0:
        return (
            "Unsure whether you mean this part or the larger object it belongs to: add a "
            "click on another part to take the whole object, or a negative click on the "
            "part that should stay out"
        )
    if res.ambiguous:
        return (
            "Unsure where the object ends (a smaller part fits your click too): add a "
            "negative click on what should stay out, or a click on a part that is missing"
        )
    return (
        "No clear edge around your click, so the selection may spill over: add a negative "
        "click on what should not be selected"
        + ("" if n_negative == 0 else ", or a click on a part that is missing")
    )

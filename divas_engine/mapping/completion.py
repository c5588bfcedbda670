"""Completion of the selection on volumetric (3DGS-derived) scenes — beyond the paper.

The paper's fusion and voxel→surfel mapping (Sec. 3.5–3.6) assume 2DGS surfels on the surface.
On a trained 3DGS the true Gaussians the paper's passes miss sit mostly in voxels no view voted
for (a 3DGS surface is a slab, or hidden behind the object's own front) and in large
translucent Gaussians whose centre voxel is inactive. Two additions, restricted to the coarse
cells around the DivAS voxel selection (:class:`CompletionConfig`):

* contribution-consistent Gaussians (in the spirit of FlashSplat): per fused view the
  blending weights split by the fused mask, ``A₁ = Σ_{M̃≥τ} α T``, ``A₀ = Σ_{M̃<τ} α T``; a
  Gaussian joins when ``A₁ − A₀ > γ √(A₀² + A₁²)`` and some view *sees* it;
* solid fill of unvoted voxels: the visual hull of the masks (on the surface or hidden within
  a silhouette's chord depth, inconsistent in no view), grown from the segmented voxels.

Incremental and exact under undo: a view's records are integers (``A₀, A₁`` in int64 fixed
point of 2⁻²⁴ pixel, voxel counters in int32) added to accumulators and subtracted on undo.
The full rules: docs/design-notes.md, section ``divas_engine/mapping/completion.py``.
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from divas_kernels import resolve_device

from ..fusion.morton import morton_decode
from ..fusion.occupancy import OccupancyGrid
from ..fusion.views import FusionView
from ..geometry import quat_rotation_entries
from ..render.config import RenderConfig
from ..render.surfel_renderer import SurfelRenderer
from ..scene import SurfelScene
from .appearance import seen_through_like_object
from .completion_gather import CoarseCells, start_gather
from .completion_records import HIDDEN as _HIDDEN
from .completion_records import INCONSISTENT as _INCONSISTENT
from .completion_records import (
    QSCALE,
    _ViewRecord,
    centre_evidence,
    gaussian_evidence,
    gaussian_geometry,
    seen_by_weight,
    voxel_evidence,
)
from .completion_records import SURFACE as _SURFACE
from .completion_records import edge_distance as _edge_distance
from .completion_sights import deep_repeats, shared_sights, voxel_repeats
from .config import CompletionConfig

__all__ = ["QSCALE", "CompletionResult", "VolumetricCompletion"]


@dataclass(eq=False)
class CompletionResult:
    """One completion (host arrays).

    Attributes:
        selected: ``[N] bool`` the DivAS selection ∪ the additions.
        contrib_added, fill_added: ``[N] bool`` Gaussians added by the contribution test /
            by their voxel (segmented or filled; not already selected).
        filled_voxels: ``[A] bool`` voxels added by the fill.
        dropped: ``[N] bool`` Gaussians of the DivAS selection dropped as
            contribution-inconsistent (``drop_inconsistent``).
        near: ``[N] bool`` Gaussians in the neighbourhood of the final voxel selection.
        rounds: fill rounds run; seconds: ``views`` (new views' records) and ``decide``.
        near_cells: ``[C+1] bool`` the coarse cells of that neighbourhood (the decision
            read the counters of their voxels and Gaussians).
    """

    selected: np.ndarray
    contrib_added: np.ndarray
    fill_added: np.ndarray
    filled_voxels: np.ndarray
    dropped: np.ndarray
    near: np.ndarray
    rounds: int
    seconds: dict = field(default_factory=dict)
    near_cells: np.ndarray | None = None

    def counts(self) -> dict[str, int]:
        return {
            "contrib_added": int(self.contrib_added.sum()),
            "fill_added": int(self.fill_added.sum()),
            "filled_voxels": int(self.filled_voxels.sum()),
            "dropped": int(self.dropped.sum()),
            "selected": int(self.selected.sum()),
        }


class VolumetricCompletion:
    """Incremental completion state of one scene on one grid (module docstring).

    Args:
        scene: the surfels (3DGS flattened; only geometry and opacity are used).
        grid: the occupancy grid of the fusion.
        active_index: ``[N] int32`` active index of each Gaussian's centre voxel (−1:
            none), e.g. :attr:`~divas_engine.mapping.SurfelMapper.active_index`.
        config: :class:`CompletionConfig`; render_config: the renderer's constants (the
            contribution weights are the rasterizer's).
        renderer: optionally the session's renderer *of this scene*: when it renders with
            ``render_config`` on ``device``, its buffers are shared and a view it has just
            rendered (binning kept) is gathered without projecting, sorting and binning
            again (same kernels, same inputs: the same records).
    """

    def __init__(
        self,
        scene: SurfelScene,
        grid: OccupancyGrid,
        active_index: np.ndarray,
        config: CompletionConfig = CompletionConfig(),
        *,
        device=None,
        render_config: RenderConfig | None = None,
        renderer=None,
    ) -> None:
        self.device = resolve_device(device if device is not None else grid.device)
        self.config = config
        self.render_config = render_config or RenderConfig()
        self.n = n = len(scene)
        self.grid = grid
        geo = grid.geometry
        self.h = float(geo.voxel_size)
        self.active_index = np.asarray(active_index, np.int64)
        if self.active_index.shape != (n,):
            raise ValueError(f"VolumetricCompletion: active_index {self.active_index.shape}")
        codes = grid.codes.numpy() if hasattr(grid.codes, "numpy") else np.asarray(grid.codes)
        self.a = len(codes)
        self.voxel_centers = geo.voxel_centers(codes)
        v_coords = morton_decode(codes)
        means = np.asarray(scene.means, np.float64)
        g_coords = np.floor((means - geo.origin) / self.h)
        g_valid = np.isfinite(g_coords).all(axis=1) & (np.abs(g_coords) < (1 << 20)).all(axis=1)
        g_coords = np.where(g_valid[:, None], g_coords, 0).astype(np.int64)
        self.cells = CoarseCells(g_coords, g_valid, v_coords, int(config.neighbourhood_log2))
        # share the renderer (and so its kept per-view binnings: the gather of a view
        # just rendered only walks its tiles) when it renders this scene with the same
        # constants; else a renderer of our own, used for the gather only
        rb = None if renderer is None else renderer.surfel_buffers  # a surfel renderer's
        if (
            rb is not None
            and len(rb) == n
            and renderer.config == self.render_config
            and rb.device == self.device
        ):
            self._renderer = renderer
        else:
            self._renderer = SurfelRenderer(scene, self.device, self.render_config)
        self.q1 = np.zeros(n, np.int64)
        self.q0 = np.zeros(n, np.int64)
        # the visibility test's geometry: centres, normals (rotation column 2) and the
        # footprint weight o · 2π s₁ s₂ of each surfel (× |cos θ| f_x f_y / z² per view)
        self.means = means
        rot = quat_rotation_entries(np.asarray(scene.quats, np.float64))
        self.normals = np.stack([rot[0][2], rot[1][2], rot[2][2]], axis=1)
        sc = np.asarray(scene.scales, np.float64)
        self.footprint = np.asarray(scene.opacities, np.float64) * 2.0 * np.pi * sc[:, 0] * sc[:, 1]
        self.colors = np.asarray(scene.base_colors(), np.float64)  # appearance rule
        self.n_seen = np.zeros(n, np.int32)
        self.n_deep_ok = np.zeros(n, np.int32)
        self.n_deep_bad = np.zeros(n, np.int32)
        self.n_surf = np.zeros(self.a, np.int32)
        self.n_hidden = np.zeros(self.a, np.int32)
        self.n_incons = np.zeros(self.a, np.int32)
        self._records: dict[int, tuple[FusionView, _ViewRecord]] = {}
        self._masks: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # centre_evidence
        self.sights: dict[int, Hashable] = {}  # view key → its sight (:meth:`sync`)
        # the cover the last decision needed (with the gather margin): a new view's
        # records are made for it at once (usually all the next decision reads)
        self._need: np.ndarray | None = None  # cells (indices)
        self._hint: np.ndarray | None = None  # their rings, made when a view is added

    # ------------------------------------------------------------------ per view
    def view_record(self, view: FusionView, cover: np.ndarray | None = None) -> _ViewRecord:
        """The integer records of one fused view (its contribution gather and its voxel
        evidence); with ``cover`` (``[C+1] bool`` coarse cells) only for the Gaussians
        and the active voxels of those cells (:meth:`_gauss_record`)."""
        pos = self._positive(view)
        rec, rho = self._record(view, cover, pos, None)
        if rec.cover is not None and not rec.cover.any():
            rec.mask = (pos, rho)  # pending: gathered by the first decision
        return rec

    def _cover_record(
        self,
        view: FusionView,
        cover: np.ndarray | None,
        pos: np.ndarray,
        rho: np.ndarray,
        sentinel: bool = True,
    ) -> _ViewRecord:
        """:meth:`view_record` from the view's mask ``pos`` and its edge distance ``rho``
        (``sentinel`` False: without the Gaussians of no cell)."""
        return self._record(view, cover, pos, rho, sentinel)[0]

    def _record(
        self,
        view: FusionView,
        cover: np.ndarray | None,
        pos: np.ndarray,
        rho: np.ndarray | None,
        sentinel: bool = True,
    ) -> tuple[_ViewRecord, np.ndarray]:
        """``(record, rho)``: :meth:`_cover_record`, with ``rho`` (None: computed here).
        The voxel part follows the Gaussian part's cover (all voxels when the gather fell
        back to the full pass). A sparse gather runs in the background
        (:func:`.completion_gather.start_gather`) while the edge distance, the voxel
        evidence and the Gaussians' geometry are made — none of them reads the walk, and
        each value is the one made after it (the same functions on the same inputs)."""
        rows, job = self._gauss_start(view, cover, pos, sentinel)
        geo = vox = None
        try:
            if rho is None:
                rho = _edge_distance(pos)
            if job is not None:
                cells = self.cells.voxels_in(np.flatnonzero(cover))
                vox = self._voxel_evidence(view, pos, rho, cells)
                geo = gaussian_geometry(self, view, pos, rho, rows)
        finally:
            out = None if job is None else job.result()
        rec = self._gauss_finish(view, cover, pos, rho, rows, out, geo)
        if rec.cover is None or vox is None:  # the full pass (or a fallback to it)
            cells = None if rec.cover is None else np.flatnonzero(rec.cover)
            vox = self._voxel_evidence(
                view, pos, rho, None if cells is None else self.cells.voxels_in(cells)
            )
        rec.voxels, rec.flags = vox
        return rec, rho

    def _positive(self, view: FusionView) -> np.ndarray:
        """The view's mask-positive pixels (``M̃ ≥ mask_threshold``)."""
        return np.asarray(view.mask).astype(np.float32, copy=False) >= np.float32(
            self.config.mask_threshold
        )

    def _mask(self, view: FusionView) -> tuple[np.ndarray, np.ndarray]:
        pos = self._positive(view)
        return pos, _edge_distance(pos)

    def _gauss_record(
        self,
        view: FusionView,
        cover: np.ndarray | None,
        pos: np.ndarray,
        rho: np.ndarray,
        sentinel: bool = True,
    ) -> _ViewRecord:
        """The Gaussian part of a view's records (no voxels): ``A₁, A₀`` in fixed point,
        seen, deep — of every Gaussian (``cover`` None: one full rasterizer pass) or of
        the Gaussians of the cells ``cover``, from the surfels that can blend before
        them (:func:`.completion_gather.sparse_contributions`: the same sums, so the
        same records for those Gaussians). The cover falls back to all when that
        sub-scene is most of the scene (or off the CPU)."""
        rows, job = self._gauss_start(view, cover, pos, sentinel)
        out = None if job is None else job.result()
        return self._gauss_finish(view, cover, pos, rho, rows, out, None)

    def _gauss_start(self, view: FusionView, cover, pos: np.ndarray, sentinel: bool):
        """``(rows, job)``: the cover's Gaussians and their sparse gather, started in the
        background (None without a cover)."""
        if cover is None:
            return None, None
        rows = self.cells.members(cover, sentinel)
        job = start_gather(self._renderer, view.camera, pos, rows, self.config.gather_max_fraction)
        return rows, job

    def _gauss_finish(self, view, cover, pos, rho, rows, out, geo) -> _ViewRecord:
        """:meth:`_gauss_record` from the sparse gather's output ``out`` (None: the full
        pass runs here) and, optionally, the geometry of ``rows`` made meanwhile."""
        if out is None:
            cover, geo = None, None
            full = self._renderer.contributions(view.camera, pos)
            rows, out = None, (full.a1.numpy(), full.a0.numpy(), self.n)
        a1 = out[0].astype(np.float64)
        a0 = out[1].astype(np.float64)
        q1 = np.rint(a1 * QSCALE).astype(np.int64)
        q0 = np.rint(a0 * QSCALE).astype(np.int64)
        nz = np.flatnonzero((q1 != 0) | (q0 != 0))
        g = (nz if rows is None else rows[nz]).astype(np.int32)
        weight = a1[nz] + a0[nz]
        if geo is None:
            seen, deep = self._gaussian_evidence(view, pos, rho, g, weight)
        else:
            seen = seen_by_weight(self, (geo[0][nz], geo[1][nz]), weight)
            deep = geo[2][nz]
        empty = np.zeros(0, np.int32)
        return _ViewRecord(g, q1[nz], q0[nz], seen, deep, empty, empty.astype(np.uint8), cover)

    # seen / depth evidence of a record's Gaussians (:func:`.completion_records.gaussian_evidence`)
    _gaussian_evidence = gaussian_evidence

    # evidence flags of (a subset of) the active voxels (:func:`.completion_records.voxel_evidence`)
    _voxel_evidence = voxel_evidence

    def _apply(self, rec: _ViewRecord, sign: int) -> None:
        self._apply_gauss(rec, sign)
        self._apply_voxels(rec, sign)

    def _apply_gauss(self, rec: _ViewRecord, sign: int) -> None:
        # the indices of a record are unique, so fancy-indexed += is exact (and far
        # cheaper than np.add.at); integer sums, so undo is exact
        self.q1[rec.gauss] += sign * rec.q1
        self.q0[rec.gauss] += sign * rec.q0
        self.n_seen[rec.gauss] += sign * rec.seen.astype(np.int32)
        self.n_deep_ok[rec.gauss] += sign * (rec.deep > 0).astype(np.int32)
        self.n_deep_bad[rec.gauss] += sign * (rec.deep < 0).astype(np.int32)

    def _apply_voxels(self, rec: _ViewRecord, sign: int) -> None:
        self.n_surf[rec.voxels] += sign * (rec.flags == _SURFACE).astype(np.int32)
        self.n_hidden[rec.voxels] += sign * (rec.flags == _HIDDEN).astype(np.int32)
        self.n_incons[rec.voxels] += sign * (rec.flags == _INCONSISTENT).astype(np.int32)

    def add_view(self, key: int, view: FusionView) -> None:
        """Add one fused view under ``key`` (e.g. its fusion slot). With
        ``sparse_gather`` its records cover the cells the last decision needed (none
        before the first decision) and :meth:`complete` widens them to what the selection
        needs (the counters hold only what the live records cover)."""
        if key in self._records:
            raise ValueError(f"completion: view {key} is already added")
        if self.config.sparse_gather:
            if self._hint is None:
                self._hint = np.zeros(self.cells.n + 1, bool)
                if self._need is not None:
                    self._hint = self.cells.rings(self._need, int(self.config.gather_margin))
            rec = self.view_record(view, self._hint.copy())
        else:
            rec = self.view_record(view)
        self._apply(rec, +1)
        self._records[key] = (view, rec)

    def remove_view(self, key: int) -> None:
        """Undo a view exactly (subtracts the integers its add and gathers added)."""
        _, rec = self._records.pop(key)
        self._masks.pop(key, None)
        self._apply(rec, -1)

    def sync(
        self,
        views: Sequence[tuple[int, FusionView]],
        sights: Mapping[int, Hashable] | None = None,
    ) -> float:
        """Make the live views exactly ``views`` (``(key, view)``; a key whose view
        object changed is removed and re-added); returns the seconds spent. ``sights``:
        the keys of views that look along one sight map to one value (a click's view and
        its wider views, :mod:`.completion_sights`): they count once where views are
        counted (None: every view a sight of its own)."""
        t = time.perf_counter()
        live = dict(views)
        self.sights = {} if sights is None else {k: sights[k] for k in live if k in sights}
        for k in [k for k, (v, _) in self._records.items() if live.get(k) is not v]:
            self.remove_view(k)
        for k, v in views:
            if k not in self._records:
                self.add_view(k, v)
        return time.perf_counter() - t

    def cover(self, need: np.ndarray, full: bool = False) -> int:
        """Make every live record hold the Gaussians and voxels of the cells ``need``
        (indices): a record whose cover lacks one is widened by the cells within
        ``gather_margin`` of ``need`` it lacks (their records gathered and added —
        integers, and each value is the whole scene's, so exact) or, when their
        sub-scene is most of the scene, replaced by the full record (always with
        ``full``). Returns the records gathered."""
        need = np.asarray(need, np.int64)
        wide = None
        done = 0
        for key, (view, rec) in list(self._records.items()):
            if rec.cover is None or rec.cover[need].all():
                continue
            if wide is None:
                wide = self.cells.rings(need, int(self.config.gather_margin))
            pos, rho = rec.mask if rec.mask is not None else self._mask(view)
            part = None
            if not full:
                part = self._cover_record(view, wide & ~rec.cover, pos, rho, sentinel=False)
            if part is not None and part.cover is not None:
                self._apply(part, +1)
                new = rec.merged(part)
                new.mask = None
            else:  # the full record replaces it (the fallback gather made it already)
                new = part if part is not None else self._cover_record(view, None, pos, rho)
                self._apply(rec, -1)
                self._apply(new, +1)
            self._records[key] = (view, new)
            done += 1
        return done

    @property
    def keys(self) -> list[int]:
        return list(self._records)

    # ------------------------------------------------------------------ decision
    def _fill_candidate(self, vox: np.ndarray, shared: list[list[int]]) -> np.ndarray:
        """Voxels ``vox`` (indices) the fill may take: consistent with one surface view
        or ``fill_min_views`` views, inconsistent with none (evaluated only for the
        voxels the fill examines, from the integer counters); ``shared``: the live views'
        groups of one sight (:func:`.completion_sights.shared_sights`), counted once."""
        ns, nh = self.n_surf[vox], self.n_hidden[vox]
        views = ns + nh
        if shared:  # a view that shares a sight adds no cone (:mod:`.completion_sights`)
            views = views - voxel_repeats(shared, self._record_map(), vox)
        ok = (ns >= 1) | (views >= self.config.fill_min_views)
        return ok & (self.n_incons[vox] == 0)

    def _record_map(self) -> dict[int, _ViewRecord]:
        return {k: rec for k, (_, rec) in self._records.items()}

    def _live_masks(self) -> list[tuple[FusionView, np.ndarray, np.ndarray]]:
        """``(view, pos, rho)`` of the live views (made once per view, for centre_evidence)."""
        for k, (v, _) in self._records.items():
            if k not in self._masks:
                self._masks[k] = self._mask(v)
        return [(v, *self._masks[k]) for k, (v, _) in self._records.items()]

    def contributions(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A₁, A₀)`` ``[N]`` float64 summed over the live views (pixels); with
        ``sparse_gather`` only the Gaussians the records cover (those the last
        :meth:`complete` read) hold their sums, the others 0."""
        return self.q1 / QSCALE, self.q0 / QSCALE

    def _decide(self, selected: np.ndarray, segmented: np.ndarray) -> CompletionResult:
        """The decision of :meth:`complete` on the records as they are (module
        docstring): ``selected`` ``[N]`` the DivAS selection, ``segmented`` ``[A]`` the
        fused voxel selection."""
        cfg = self.config
        t = time.perf_counter()
        sel = np.asarray(selected, bool)
        seg = np.asarray(segmented, bool)
        if sel.shape != (self.n,) or seg.shape != (self.a,):
            raise ValueError(
                f"complete: selection {sel.shape} / voxels {seg.shape}, "
                f"expected ({self.n},) / ({self.a},)"
            )
        # solid fill: grow from the segmented voxels through consistent, never
        # inconsistent voxels, one neighbourhood per round. Only the voxels of the cells
        # that became near since the last round are examined (every candidate of an
        # older near cell joined in the round its cell became near), so the work is
        # the cells near the selection and their voxels, not A or N.
        cur = seg.copy()
        near_cells = np.zeros(self.cells.n + 1, bool)
        fresh = self.cells.dilate_into(near_cells, np.flatnonzero(seg))
        near_list = [fresh]
        rounds = 0
        shared = shared_sights(self.sights, list(self._records))  # once per decision
        for _ in range(cfg.fill_rounds):
            vox = self.cells.voxels_in(fresh)
            vox = vox[~cur[vox]]
            new = vox[self._fill_candidate(vox, shared)]
            if len(new) == 0:
                break
            cur[new] = True
            rounds += 1
            fresh = self.cells.dilate_into(near_cells, new)
            near_list.append(fresh)
        filled = cur & ~seg
        # Gaussian level, evaluated on the neighbourhood's Gaussians only (member lists
        # of the near cells: O(Gaussians near the selection))
        g_near = self.cells.gaussians_in(np.concatenate(near_list))
        near = np.zeros(self.n, bool)
        near[g_near] = True
        idx = g_near[~sel[g_near]]
        a1 = self.q1[idx].astype(np.float64)
        a0 = self.q0[idx].astype(np.float64)
        seen = (a1 + a0) >= cfg.min_weight * QSCALE
        positive = seen & (a1 - a0 > cfg.gamma * np.hypot(a1, a0))
        negative = seen & ~positive
        # the masks claim only what they show: a Gaussian seen through other surfaces in
        # every view joins as the fill's hidden voxels do (module docstring)
        ok_deep = self.n_deep_bad[idx] == 0
        shown = self.n_seen[idx] >= 1
        deep_views = self.n_deep_ok[idx]
        if shared:
            deep_views = deep_views - deep_repeats(shared, self._record_map(), idx)
        through = positive & ~(shown | (ok_deep & (deep_views >= cfg.fill_min_views)))
        positive &= ~through
        if cfg.appearance_k > 0 and through.any():
            # … or when it looks like the object's seen Gaussians next to it (appearance)
            j = np.flatnonzero(through)
            obj = sel.copy()
            obj[idx[positive]] = True
            like = seen_through_like_object(self, idx[j], obj, near, cfg.min_weight * QSCALE)
            positive[j[like]] = True
            through[j[like]] = False
        # in a segmented or filled voxel, one view that puts the centre within the solid
        # depth suffices (the voxel carries the rest of the evidence)
        through &= ~(ok_deep & (self.n_deep_ok[idx] >= 1))
        act = self.active_index[idx]
        in_voxels = np.zeros(len(idx), bool)
        ok = act >= 0
        in_voxels[ok] = cur[act[ok]]  # centre voxel segmented or filled
        contrib_add = np.zeros(self.n, bool)
        fill_add = np.zeros(self.n, bool)
        contrib_add[idx[positive]] = True
        by_voxel = in_voxels & ~negative & ~through
        if cfg.centre_evidence:  # the voxel's claim, tested at the Gaussian's own centre
            j = np.flatnonzero(by_voxel & ~positive)
            if len(j):
                by_voxel[j[~centre_evidence(self, self._live_masks(), self.means[idx[j]])]] = False
        fill_add[idx[by_voxel & ~positive]] = True
        out = sel.copy()
        out[idx[positive | by_voxel]] = True
        dropped = np.zeros(self.n, bool)
        if cfg.drop_inconsistent:
            j = np.flatnonzero(sel)
            b1 = self.q1[j].astype(np.float64)
            b0 = self.q0[j].astype(np.float64)
            ev = (b1 + b0) >= cfg.drop_min_weight * QSCALE
            bad = ev & ~(b1 - b0 > cfg.gamma * np.hypot(b1, b0))
            dropped[j[bad]] = True
            out[j[bad]] = False
        return CompletionResult(
            selected=out,
            contrib_added=contrib_add,
            fill_added=fill_add,
            filled_voxels=filled,
            dropped=dropped,
            near=near,
            rounds=rounds,
            seconds={"decide": time.perf_counter() - t},
            near_cells=near_cells,
        )

    # ------------------------------------------------------------------ records' cover
    # The decision above reads the records of the Gaussians of the cells near the
    # selection (grown by the fill) and of the selected ones. With the sparse gather each
    # live record holds only the Gaussians and voxels of its cover, so ``complete``
    # first widens the covers to what any decision reads (the cells next to the
    # segmented voxels, the selected Gaussians' cells), decides, widens them to what that
    # decision read (the fill may have grown the neighbourhood) and, if it had to,
    # decides again — until no cover lacks a cell. A decision whose reads were all
    # covered saw the counters of the full records, so it is the full records' decision.
    # The decision itself is ``_decide``.
    def complete(self, selected: np.ndarray, segmented: np.ndarray) -> CompletionResult:
        """The completed selection from the DivAS selection ``selected`` ``[N]`` and the
        fused voxel selection ``segmented`` ``[A]`` (module docstring): the decision on
        records that cover everything it reads (:meth:`cover`)."""
        sel = np.asarray(selected, bool)
        seg = np.asarray(segmented, bool)
        sparse = self.config.sparse_gather and bool(self._records)
        t = time.perf_counter()
        gathered = rounds = 0
        if sparse:
            sel_cells = self.cells.of_gauss[np.flatnonzero(sel)]
        if sparse and any(r.mask is not None for _, r in self._records.values()):
            # a record that covers nothing yet (no decision before it): what any decision
            # reads at least, before the first one (saves widening rounds)
            mark = np.zeros(self.cells.n + 1, bool)
            self.cells.dilate_into(mark, np.flatnonzero(seg))
            mark[sel_cells] = True
            gathered = self.cover(np.flatnonzero(mark[: self.cells.n]))
        t_gather = time.perf_counter() - t
        res = self._decide(sel, seg)
        while sparse:
            mark = res.near_cells.copy()
            mark[sel_cells] = True
            need = np.flatnonzero(mark[: self.cells.n])
            t = time.perf_counter()
            got = self.cover(need, full=rounds >= self.config.fill_rounds + 2)
            t_gather += time.perf_counter() - t
            if not got:
                if self._need is None or not np.array_equal(need, self._need):
                    self._need, self._hint = need, None
                break
            gathered += got
            rounds += 1
            res = self._decide(sel, seg)
        res.seconds["gather"] = t_gather
        res.seconds["rounds"] = rounds
        res.seconds["gathered"] = gathered
        return res

"""2DGS voxel-to-surfel mapping: the three-pass monotone chain f¹ ⪰ f² ⪰ f (paper
Sec. 3.6 "Voxel-to-Surfel Mapping and Aggregation", eq:pass1 … eq:final-F; App. B;
alg:vox2surfel; kernels in ``kernels/coverage.py``).

Usage::

    mapper = SurfelMapper(scene, grid)          # uploads surfels once, τ_a once
    res = mapper.map(fusion.result(), views, slots)   # after each accepted view
    res.selected                                # [N] bool, the foreground indicator f

``slots[k]`` is the view-coverage bitmask bit of ``views[k]`` (for
:class:`~divas_engine.fusion.GsFusion` the id returned by ``add_view``). The decisions on
points the paper leaves open (voxel resolution, τ_a's percentile, the 1σ box, per-pixel
acceptance, near-plane rule, κ's float32 arithmetic) are listed in docs/design-notes.md.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

# the kernel boundary: only names of divas_kernels.__all__ (coverage and occupancy
# wrappers under their old module aliases, to keep this diff to the imports)
import divas_kernels as kcov
import divas_kernels as kocc
from divas_kernels import (
    DeviceArray,
    cpu_threads,
    device_append,
    device_synchronize,
    device_zeros,
    resolve_device,
    to_device,
)

from ..fusion.occupancy import OccupancyGrid, surfel_voxel_codes
from ..fusion.state import FusionResult
from ..fusion.views import FusionView
from ..scene import SurfelScene
from .config import MappingConfig

__all__ = ["MappingResult", "SurfelMapper", "map_to_surfels", "needle_threshold", "surfel_aspects"]


def surfel_aspects(scales: np.ndarray, eps: float) -> np.ndarray:
    """eq:aspect: ``a_i = max(s₁, s₂) / (min(s₁, s₂) + ε)``, float64 ``[N]``."""
    s = np.asarray(scales, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 2:
        raise ValueError(f"surfel_aspects: scales must be [N,2], got {s.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):
        return s.max(axis=1) / (s.min(axis=1) + eps)


def needle_threshold(aspects: np.ndarray, percentile: float) -> tuple[float, np.ndarray]:
    """eq:needle / eq:pass-needle: ``τ_a`` and the ``[N] bool`` keep flags ``a_i ≤ τ_a``."""
    fin = np.isfinite(aspects)
    if not fin.any():
        return float("inf"), np.zeros(len(aspects), dtype=bool)
    tau = float(np.percentile(aspects[fin], percentile))
    with np.errstate(invalid="ignore"):
        return tau, fin & (aspects <= tau)


@dataclass(eq=False)
class MappingResult:
    """Output of one mapping run (host arrays).

    Attributes:
        selected: ``[N] bool`` final indicator f = f³ (eq:final-F).
        pass1, pass2: ``[N] bool`` f¹ (eq:pass1), f² (eq:pass-needle).
        kappa: ``[N] float32`` max-over-views coverage κ (eq:kappa); 0 where not scored.
        tau_a: the needle threshold τ_a (eq:needle).
        n_pass1, n_pass2, n_selected: surfels kept by each pass.
        n_needles: surfels of the whole scene with ``a_i > τ_a``.
        scored_per_view: ``|a_s|`` per view — Pass-2 survivors whose voxel has the view's
            bit (alg:vox2surfel (i)); ``n_scored`` their sum.
        seconds: wall times of ``pass1``, ``pass2`` (+ candidate compaction), ``views``
            (binarise/upload new views' masks, bitmask upload), ``pass3`` (gather, final
            threshold), ``readback`` and ``total``.
    """

    selected: np.ndarray
    pass1: np.ndarray
    pass2: np.ndarray
    kappa: np.ndarray
    tau_a: float
    n_pass1: int
    n_pass2: int
    n_selected: int
    n_needles: int
    scored_per_view: list[int]
    n_scored: int
    seconds: dict[str, float] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        return {
            "pass1": self.n_pass1,
            "pass2": self.n_pass2,
            "selected": self.n_selected,
            "needles": self.n_needles,
            "scored": self.n_scored,
        }


class _ViewCache:
    """Per-view binarised masks (``M̃ ≥ τ_M``, uint8) and their summed-area tables
    (int32, ``(H+1)×(W+1)``), resident in two append-only device buffers.

    A view is binarised and uploaded once, when it first appears; later calls only
    rebuild the tiny per-view struct array. Space of dropped views is reclaimed by a
    rebuild when it exceeds the live space.
    """

    min_reclaim = 1 << 20  # bytes of dropped masks tolerated before a rebuild

    def __init__(self, device) -> None:
        self.device = device
        self.res: dict[int, tuple[FusionView, float, int, int, int, int]] = {}
        self.mbuf = device_zeros(0, np.uint8, device)
        self.sbuf = device_zeros(0, np.int32, device)
        self.mused = self.sused = 0
        self.key: tuple | None = None
        self.views_dev: DeviceArray | None = None

    @staticmethod
    def binarise(v: FusionView, tau_m: float) -> tuple[np.ndarray, np.ndarray]:
        m = np.asarray(v.mask)
        b = (m.astype(np.float32, copy=False) >= np.float32(tau_m)).astype(np.uint8)
        sat = np.zeros((b.shape[0] + 1, b.shape[1] + 1), dtype=np.int32)
        np.cumsum(np.cumsum(b, axis=0, dtype=np.int32), axis=1, dtype=np.int32, out=sat[1:, 1:])
        return b.ravel(), sat.ravel()

    def buffers(
        self, views: Sequence[FusionView], slots: Sequence[int], cfg: MappingConfig
    ) -> tuple[DeviceArray, DeviceArray, DeviceArray]:
        tau = float(cfg.mask_threshold)
        key = (tuple(id(v) for v in views), tuple(int(s) for s in slots), tau, float(cfg.near))
        if key == self.key and self.views_dev is not None:
            return self.views_dev, self.mbuf, self.sbuf
        live = {id(v): v for v in views}
        for k in [
            k for k, e in self.res.items() if k not in live or e[0] is not live[k] or e[1] != tau
        ]:
            del self.res[k]
        live_m = sum(e[4] for e in self.res.values())
        if self.mused - live_m > max(live_m, self.min_reclaim):  # reclaim dropped views' space
            self.res.clear()
            self.mused = self.sused = 0
        for v in views:
            if id(v) not in self.res:
                b, sat = self.binarise(v, tau)
                moff, soff = self.mused, self.sused
                self.mbuf, self.mused = device_append(self.mbuf, self.mused, b)
                self.sbuf, self.sused = device_append(self.sbuf, self.sused, sat)
                self.res[id(v)] = (v, tau, moff, soff, b.size, sat.size)
        structs = []
        for v, s in zip(views, slots):
            _, _, moff, soff, _, _ = self.res[id(v)]
            c = v.camera
            structs.append(
                kcov.make_coverage_view(
                    c.w2c,
                    c.fx,
                    c.fy,
                    c.cx,
                    c.cy,
                    c.width,
                    c.height,
                    c.clip_near(cfg.near),
                    int(s),
                    moff,
                    soff,
                )
            )
        self.views_dev = kcov.upload_coverage_views(structs, self.device)
        self.key = key
        return self.views_dev, self.mbuf, self.sbuf


class SurfelMapper:
    """Voxel-to-surfel mapping of one scene on one grid, cheap to re-run per update.

    The constructor uploads the surfel centres and scaled tangents, resolves every
    surfel's voxel (Pass-1 Morton code → active index) and computes the per-scene
    needle threshold; :meth:`map` then costs three light per-surfel kernels plus the
    Pass-3 gather over the candidates.

    Args:
        scene: the surfels.
        grid: the occupancy grid the fusion ran on (same device).
        config: default :class:`MappingConfig` for :meth:`map`.
        device: Warp device (default: the grid's).
        surfels: the scene's :class:`divas_kernels.SurfelBuffers` on the same device (a
            renderer's ``surfel_buffers``): their centres and scaled tangents are used
            instead of a second upload. They hold the same float32 values: the renderer
            rounds the float32 product ``R·s`` and this class the exact float64 product
            of the same float32 factors, which rounds to the same float32 (tested bit
            for bit).
    """

    def __init__(
        self,
        scene: SurfelScene,
        grid: OccupancyGrid,
        config: MappingConfig = MappingConfig(),
        device=None,
        surfels=None,
    ) -> None:
        self.device = grid.device if device is None else resolve_device(device)
        if self.device != grid.device:
            raise ValueError(f"SurfelMapper: grid lives on {grid.device}, asked for {self.device}")
        self.grid = grid
        self.config = config
        self.n = n = len(scene)
        d = self.device
        if surfels is not None and surfels.device == d and len(surfels) == n:
            self._means, self._tu, self._tv = surfels.means, surfels.tu, surfels.tv
        else:
            rot = scene.rotations().astype(np.float64)
            sc = np.asarray(scene.scales, dtype=np.float64)
            f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
            self._means = to_device(f32(scene.means), d, vec3=True)
            self._tu = to_device(f32(rot[:, :, 0] * sc[:, :1]), d, vec3=True)
            self._tv = to_device(f32(rot[:, :, 1] * sc[:, 1:2]), d, vec3=True)
            del rot, sc
        codes = surfel_voxel_codes(self._means, grid.geometry, device=d)
        self._act = kocc.hash_query(
            grid.hash_keys, grid.hash_vals, grid.hash_shift, codes, device=d
        )
        self._act_host = self._act.numpy().copy()
        self._scales = scene.scales  # a reference (other ε only)
        self._aspects = surfel_aspects(scene.scales, config.aspect_eps)
        self._needle: dict[tuple[float, float], tuple[float, np.ndarray, DeviceArray]] = {}
        self._needle_entry(config)
        self._views = _ViewCache(d)
        self._f1 = device_zeros(n, np.uint8, d)
        self._f2 = device_zeros(n, np.uint8, d)
        self._sel = device_zeros(n, np.uint8, d)
        self._flag = device_zeros(n, np.int32, d)
        self._kappa = device_zeros(n, np.float32, d)
        self._scored = device_zeros(n, np.int32, d)
        self._ones = to_device(np.ones(n, np.uint8), d)

    # --- per-scene state ----------------------------------------------------------
    def _needle_entry(self, cfg: MappingConfig) -> tuple[float, np.ndarray, DeviceArray]:
        key = (float(cfg.needle_percentile), float(cfg.aspect_eps))
        e = self._needle.get(key)
        if e is None:
            a = (
                self._aspects
                if cfg.aspect_eps == self.config.aspect_eps
                else surfel_aspects(self._scales, cfg.aspect_eps)
            )
            tau, keep = needle_threshold(a, cfg.needle_percentile)
            e = (tau, keep, to_device(keep.astype(np.uint8), self.device))
            self._needle[key] = e
        return e

    @property
    def active_index(self) -> np.ndarray:
        """``[N] int32`` active index of each surfel's voxel (−1: filtered/inactive)."""
        return self._act_host

    @property
    def selected_device(self) -> DeviceArray:
        """``[N] uint8`` f of the last :meth:`map` on the device (overwritten by the next)."""
        return self._sel

    @property
    def aspects(self) -> np.ndarray:
        return self._aspects

    # --- validation ---------------------------------------------------------------
    def _check(
        self, fused: FusionResult, views: Sequence[FusionView], slots: Sequence[int]
    ) -> np.ndarray:
        if fused.vmask is None:
            raise ValueError(
                "map_to_surfels: the fusion result has no view bitmask "
                "(a NeRF result?); the mapping needs the 2DGS GsFusion result"
            )
        a = len(self.grid)
        if len(fused.segmented) != a or fused.vmask.shape[0] != a:
            raise ValueError(
                f"map_to_surfels: fusion result has {len(fused.segmented)} voxels, the grid {a}"
            )
        if len(views) != len(slots):
            raise ValueError(f"map_to_surfels: {len(views)} views but {len(slots)} slots")
        bits = 32 * (fused.vmask.shape[1] if fused.vmask.ndim == 2 else 0)
        sl = [int(s) for s in slots]
        for s in sl:
            if not 0 <= s < bits:
                raise ValueError(f"map_to_surfels: slot {s} outside the bitmask [0, {bits})")
        if len(set(sl)) != len(sl):
            raise ValueError(f"map_to_surfels: duplicate slots {sl}")
        return np.ascontiguousarray(fused.vmask, dtype=np.uint32).reshape(a, -1)

    # --- the mapping --------------------------------------------------------------
    def map(
        self,
        fused: FusionResult,
        views: Sequence[FusionView],
        slots: Sequence[int],
        config: MappingConfig | None = None,
    ) -> MappingResult:
        """Run Passes 1–3 for the fused state ``fused`` and its live ``views``/``slots``."""
        cfg = config or self.config
        d = self.device
        vm = self._check(fused, views, slots)
        sec: dict[str, float] = {}
        t_all = t = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal t
            device_synchronize(d)
            now = time.perf_counter()
            sec[name] = now - t
            t = now

        thr = cpu_threads(cfg.threads)
        seg = to_device(np.asarray(fused.segmented, dtype=np.uint8), d)
        kcov.run_pass1(self._act, seg, self._f1, d, thr)
        lap("pass1")
        tau_a, keep_h, keep = self._needle_entry(cfg)
        if not cfg.needle_filter:
            keep = self._ones
        kcov.run_pass2(self._f1, keep, self._f2, self._flag, d, thr)
        cand = kcov.compact(self._flag, d)
        self._kappa.zero_()
        self._scored.zero_()
        lap("pass2")
        run3 = cfg.coverage_filter and len(views) > 0 and cand.shape[0] > 0
        if run3:
            vdev, mdev, sdev = self._views.buffers(views, slots, cfg)
            vmask = to_device(vm, d)
        lap("views")
        if run3:
            kcov.run_coverage(
                cand,
                self._act,
                vmask,
                self._means,
                self._tu,
                self._tv,
                vdev,
                mdev,
                sdev,
                cfg.box_sigma,
                cfg.accept_sigma,
                cfg.early_out,
                self._kappa,
                self._scored,
                device=d,
                threads=thr,
            )
        kcov.run_select(
            self._f2, self._kappa, cfg.surfel_coverage, cfg.coverage_filter, self._sel, d, thr
        )
        lap("pass3")
        f1 = self._f1.numpy().astype(bool)
        f2 = self._f2.numpy().astype(bool)
        sel = self._sel.numpy().astype(bool)
        kappa = self._kappa.numpy().copy()
        per_view = self._scored_per_view(f2, vm, slots) if cfg.coverage_filter else [0] * len(views)
        lap("readback")
        sec["total"] = time.perf_counter() - t_all
        return MappingResult(
            selected=sel,
            pass1=f1,
            pass2=f2,
            kappa=kappa,
            tau_a=tau_a,
            n_pass1=int(f1.sum()),
            n_pass2=int(f2.sum()),
            n_selected=int(sel.sum()),
            n_needles=int((~keep_h).sum()),
            scored_per_view=per_view,
            n_scored=int(sum(per_view)),
            seconds=sec,
        )

    def _scored_per_view(self, f2: np.ndarray, vm: np.ndarray, slots: Sequence[int]) -> list[int]:
        """|a_s| per view: candidates per voxel, then each view's bit (host,
        O(N + V·S) with V the voxels holding candidates)."""
        idx = self._act_host[f2]
        if idx.size == 0 or vm.size == 0:
            return [0] * len(slots)
        per_vox = np.bincount(idx, minlength=vm.shape[0])
        nz = np.flatnonzero(per_vox)  # voxels holding candidates (≪ A)
        cnt, rows = per_vox[nz], vm[nz]
        out = []
        for s in slots:
            s = int(s)
            has = ((rows[:, s // 32] >> np.uint32(s % 32)) & np.uint32(1)).astype(bool)
            out.append(int(cnt[has].sum()))
        return out

    def view_counts(
        self, fused: FusionResult, view: FusionView, slot: int, config: MappingConfig | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw ``(total_fp, mask_fp, scored)`` ``[N]`` of one view (eq:cov-atomics), full
        sweeps without early-outs; zero for surfels not in ``a_s``."""
        cfg = config or self.config
        d = self.device
        vm = self._check(fused, [view], [slot])
        n = self.n
        seg = to_device(np.asarray(fused.segmented, dtype=np.uint8), d)
        _, _, keep = self._needle_entry(cfg)
        if not cfg.needle_filter:
            keep = self._ones
        tot = device_zeros(n, np.int32, d)
        pos = device_zeros(n, np.int32, d)
        kap = device_zeros(n, np.float32, d)
        scored = device_zeros(n, np.int32, d)
        if n:
            f1 = device_zeros(n, np.uint8, d)
            f2 = device_zeros(n, np.uint8, d)
            flag = device_zeros(n, np.int32, d)
            kcov.run_pass1(self._act, seg, f1, d)
            kcov.run_pass2(f1, keep, f2, flag, d)
            cand = kcov.compact(flag, d)
            vdev, mdev, sdev = _ViewCache(d).buffers([view], [slot], cfg)
            if cand.shape[0]:
                kcov.run_coverage(
                    cand,
                    self._act,
                    to_device(vm, d),
                    self._means,
                    self._tu,
                    self._tv,
                    vdev,
                    mdev,
                    sdev,
                    cfg.box_sigma,
                    cfg.accept_sigma,
                    False,
                    kap,
                    scored,
                    tot,
                    pos,
                    device=d,
                    threads=cpu_threads(cfg.threads),
                )
        return tot.numpy(), pos.numpy(), scored.numpy().astype(bool)


def map_to_surfels(
    scene: SurfelScene,
    grid: OccupancyGrid,
    fused: FusionResult,
    views: Sequence[FusionView],
    slots: Sequence[int],
    config: MappingConfig = MappingConfig(),
    device=None,
) -> MappingResult:
    """One-shot mapping (builds a :class:`SurfelMapper`; keep one to re-run per update)."""
    return SurfelMapper(scene, grid, config, device).map(fused, views, slots, config)

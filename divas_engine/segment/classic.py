"""A weight-free fallback segmenter: seeded GrabCut on colour *and* rendered depth.

No model file, no network (the default is the scene-aware :mod:`.graph3d`). It keeps SAM's
contract (3 granularities, probabilities, a score per channel) so the rest of DivAS cannot
tell the difference. Per prompt set, at SAM's low-res scale: Lab colour on two principal axes
plus a depth channel ``128 + depth_gain · δ`` with ``δ`` the signed log-distance to the
positive clicks' depth band (the idea of eq:depthband); seeds from the band (or, with
``edge_regions``, from the click's depth-edge region, :mod:`.depth_edges`); ``cv2.grabCut``
in an ROI; soft output ``sigmoid(sd / softness_px)``; score per channel from the boundary
separation ``D² / (1 + D²)``. Channels are small/medium/large by the tolerance ``τ_k``.
The steps in full: docs/design-notes.md, section ``divas_engine/segment/classic.py``.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from . import depth_edges as de
from .base import Segmenter, pixel_index
from .sam_common import sigmoid

__all__ = ["ClassicConfig", "ClassicSegmenter"]


@dataclass(frozen=True)
class ClassicConfig:
    """Knobs of :class:`ClassicSegmenter` (none come from the paper: the paper uses SAM).

    Attributes:
        work_long_side: working resolution, longest side (SAM's low-res grid is 256).
        depth_tol: ``τ_k`` per granularity (small, medium, large), log-depth units
            (≈ relative depth) around the click band for the probable foreground.
        hard_factor: sure background beyond ``hard_factor · τ_k``.
        colour_tol: Lab distance per granularity replacing ``τ_k`` when there is no depth.
        neg_colour_margin: a pixel leaves the probable foreground when its Lab colour is
            nearer the negative clicks' mean than the positive clicks' by this margin.
        depth_gain: grey levels per unit of log depth in the depth channel.
        seed_radius: click disk radius, working-resolution pixels.
        iterations: GrabCut iterations per granularity.
        cut_scale: extra resampling of the cut per granularity (the large one runs
            at half the working resolution: coarse masks, bounded time).
        roi_margin: ROI margin around the probable foreground, fraction of the working size.
        softness_px: sigmoid scale of the soft boundary, full-resolution pixels.
        sep_floor: ``σ₀`` (grey levels) in the separation score.
        max_area_frac: masks covering more of the view score 0.
        min_area_frac: smaller masks (a click that did not grow) score ∝ their area.
        seed: OpenCV RNG seed (GrabCut's k-means), for reproducible masks.
        edge_regions: use the depth-edge region as GrabCut's initial labelling (module
            docstring; only when depth is given).
        jump_tol: relative disparity jump per granularity that counts as a depth edge.
        crease_tol: normal crease angle (radians) per granularity that counts as an edge.
        focal_frac: focal length assumed for the pseudo-normals, fraction of the working width.
        crease_gap: normals compared this many pixels on either side of a pixel pair.
        crease_gate, crease_gate_px: creases are ignored within ``crease_gate_px`` of a
            jump stronger than ``crease_gate · jump_tol`` (a jump's rim is no crease).
        regrow_px: the edge-free core re-grows this far over its rim where depth continues.
        hole_px: depth holes up to this area (working pixels) are filled before edges.
        edge_hard_factor: band factor (× ``τ_k``) of the edge-region path.
        closure_power: exponent of the closure factor in the score (0 disables it).
        edge_min_score: below this, a channel in ``edge_fallback`` falls back to the
            depth-band labels (default: only channel 1, the one DivAS fuses — the
            fallback is a second GrabCut, so the other channels skip it for time).
    """

    work_long_side: int = 256
    depth_tol: tuple[float, float, float] = (0.05, 0.12, 0.25)
    hard_factor: float = 2.0
    colour_tol: tuple[float, float, float] = (15.0, 30.0, 50.0)
    neg_colour_margin: float = 10.0
    depth_gain: float = 400.0
    seed_radius: int = 2
    iterations: tuple[int, int, int] = (1, 2, 1)
    cut_scale: tuple[float, float, float] = (1.0, 1.0, 0.5)
    roi_margin: float = 0.15
    softness_px: float = 1.0
    sep_floor: float = 2.0
    max_area_frac: float = 0.95
    min_area_frac: float = 0.002
    seed: int = 0
    edge_regions: bool = True
    jump_tol: tuple[float, float, float] = (0.02, 0.04, 0.08)
    crease_tol: tuple[float, float, float] = (0.5, 0.8, 1.2)
    focal_frac: float = 1.0
    crease_gap: int = 1
    crease_gate: float = 0.5
    crease_gate_px: int = 4
    regrow_px: int = 2
    hole_px: int = 30
    edge_hard_factor: float = 3.0
    closure_power: float = 1.0
    edge_min_score: float = 0.5
    edge_fallback: tuple[int, ...] = (1,)


def _disk(shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray, r: int) -> np.ndarray:
    out = np.zeros(shape, np.uint8)
    for y, x in zip(rows.tolist(), cols.tolist()):
        cv2.circle(out, (int(x), int(y)), int(r), 1, thickness=-1)
    return out.astype(bool)


def _components_with(
    mask: np.ndarray, rows: np.ndarray, cols: np.ndarray, connectivity: int = 8
) -> np.ndarray:
    """Union of the connected components of ``mask`` that contain a given pixel."""
    n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=connectivity)
    ids = np.unique(lab[rows, cols])
    ids = ids[ids > 0]
    return np.isin(lab, ids) if ids.size else np.zeros_like(mask, bool)


class ClassicSegmenter(Segmenter):
    """Seeded GrabCut on colour + depth (module docstring); works without weights."""

    name = "classic"

    def __init__(self, config: ClassicConfig | None = None, cache_size: int = 8):
        super().__init__(cache_size)
        self.config = config or ClassicConfig()

    # -- per view ---------------------------------------------------------------
    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        cfg = self.config
        h, w = rgb.shape[:2]
        f = min(1.0, cfg.work_long_side / max(h, w))
        hh, ww = max(1, int(round(h * f))), max(1, int(round(w * f)))
        small = cv2.resize(rgb, (ww, hh), interpolation=cv2.INTER_AREA) if f < 1 else rgb
        lab = cv2.cvtColor(
            np.clip(small * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2Lab
        ).astype(np.float32)
        flat = lab.reshape(-1, 3)
        centred = flat - flat.mean(axis=0)
        _, vecs = np.linalg.eigh(centred.T @ centred / max(1, len(flat)))
        colour2 = np.clip(centred @ vecs[:, ::-1][:, :2] + 128.0, 0, 255).reshape(hh, ww, 2)
        logd = None
        if depth is not None:
            valid = (depth > 0).astype(np.float32)
            ld = np.log(np.where(depth > 0, depth, 1.0)).astype(np.float32) * valid
            if f < 1:
                num = cv2.resize(ld, (ww, hh), interpolation=cv2.INTER_AREA)
                den = cv2.resize(valid, (ww, hh), interpolation=cv2.INTER_AREA)
            else:
                num, den = ld, valid
            logd = np.where(den >= 0.5, num / np.maximum(den, 1e-6), np.inf).astype(np.float32)
        edges = None
        if logd is not None and cfg.edge_regions:
            logd = de.fill_small_holes(logd, cfg.hole_px)
            with np.errstate(over="ignore"):
                q = np.exp(-logd).astype(np.float32)  # disparity; no surface → 0
            jh, jv = de.pair_jumps(np.where(np.isfinite(logd), q, np.nan).astype(np.float32))
            ch, cv = de.pair_creases(q, cfg.focal_frac * ww, cfg.crease_gap)
            edges = (de.pixel_strength(jh, jv), de.pixel_strength(ch, cv))
        return {
            "edges": edges,
            "strength": {},
            "lab": lab,
            "colour2": colour2.astype(np.float32),
            "logd": logd,
            "depth": depth,
            "full": (h, w),
            "work": (hh, ww),
        }

    # -- per prompt set ------------------------------------------------------------
    def _click_logdepth(self, depth: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        out = np.full(len(rows), np.nan)
        for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist())):
            win = depth[max(r - 2, 0) : r + 3, max(c - 2, 0) : c + 3]
            win = win[win > 0]
            if win.size:
                out[i] = np.log(np.median(win))
        return out

    def _predict(
        self, st: Any, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        h, w = st["full"]
        hh, ww = st["work"]
        pos, neg = points[labels == 1], points[labels == 0]
        if len(pos) == 0:
            return np.zeros((3, h, w), np.float32), np.zeros(3, np.float32)
        scale = np.array([ww / w, hh / h])
        pr, pc = pixel_index(pos * scale, (hh, ww))
        nr, nc = pixel_index(neg * scale, (hh, ww))
        lab = st["lab"]

        delta = None
        if st["logd"] is not None:
            fr, fc = pixel_index(pos, (h, w))
            band = self._click_logdepth(st["depth"], fr, fc)
            band = band[np.isfinite(band)]
            if band.size:
                ld = st["logd"]
                lo, hi = float(band.min()), float(band.max())
                delta = np.where(np.isfinite(ld), ld - np.clip(ld, lo, hi), np.inf)
        if delta is not None:
            dchan = np.clip(128.0 + cfg.depth_gain * np.minimum(delta, 1e3), 0, 255)
            dchan = np.where(np.isfinite(delta), dchan, 255.0)
        else:  # no depth: third channel is Lab lightness
            dchan = lab[..., 0]
        feat = np.dstack([st["colour2"], dchan]).astype(np.float32)
        feat8 = np.clip(feat + 0.5, 0, 255).astype(np.uint8)

        pos_col = lab[pr, pc].mean(axis=0)
        coldist = np.linalg.norm(lab - pos_col, axis=2)
        nearer_neg = np.zeros((hh, ww), bool)
        if len(neg):
            neg_dist = np.linalg.norm(lab - lab[nr, nc].mean(axis=0), axis=2)
            nearer_neg = neg_dist + cfg.neg_colour_margin < coldist
        pos_disk = _disk((hh, ww), pr, pc, cfg.seed_radius)
        neg_disk = _disk((hh, ww), nr, nc, cfg.seed_radius)

        masks = np.zeros((3, h, w), np.float32)
        scores = np.zeros(3, np.float32)
        done: dict[bytes, np.ndarray] = {}
        for k in (1, 0, 2):  # medium first: a channel whose initial labels equal it reuses it
            edge = st["edges"] is not None
            if delta is not None:
                tol = cfg.depth_tol[k]
                inband = np.abs(delta) <= tol
                sure_bg = np.abs(delta) > (cfg.edge_hard_factor if edge else cfg.hard_factor) * tol
                seeds = pos_disk & inband
                seeds[pr, pc] = True
            else:
                inband = coldist <= cfg.colour_tol[k]
                sure_bg = np.zeros((hh, ww), bool)
                seeds = pos_disk
            closure = 1.0
            if edge:
                init, closure = self._edge_labels(
                    st, k, sure_bg, seeds, neg_disk, nearer_neg, pr, pc, nr, nc
                )
            else:
                init = self._init_labels(inband, sure_bg, seeds, neg_disk, nearer_neg, pr, pc)
            key = init.tobytes()
            if key not in done:
                done[key] = self._grabcut(
                    feat8, init, pr, pc, nr, nc, cfg.iterations[k], cfg.cut_scale[k]
                )
            binary = done[key]
            score = self._score(binary, feat, pr, pc, nr, nc) * closure**cfg.closure_power
            if edge and k in cfg.edge_fallback and score < cfg.edge_min_score:  # plain band
                hf = cfg.hard_factor * cfg.depth_tol[k]
                init = self._init_labels(
                    inband,
                    np.abs(delta) > hf if delta is not None else np.zeros((hh, ww), bool),
                    seeds,
                    neg_disk,
                    nearer_neg,
                    pr,
                    pc,
                )
                key = init.tobytes()
                if key not in done:
                    done[key] = self._grabcut(
                        feat8, init, pr, pc, nr, nc, cfg.iterations[k], cfg.cut_scale[k]
                    )
                binary = done[key]
                score = self._score(binary, feat, pr, pc, nr, nc)
            masks[k] = self._soften(binary, (h, w))
            scores[k] = score
        return masks, scores

    def _init_labels(
        self,
        inband: np.ndarray,
        sure_bg: np.ndarray,
        seeds: np.ndarray,
        neg_disk: np.ndarray,
        nearer_neg: np.ndarray,
        pr: np.ndarray,
        pc: np.ndarray,
    ) -> np.ndarray:
        """GrabCut's initial label image (module docstring, step 3)."""
        hh, ww = inband.shape
        region = (_components_with(inband, pr, pc) & ~nearer_neg) | seeds
        gc = np.full((hh, ww), cv2.GC_PR_BGD, np.uint8)
        gc[region] = cv2.GC_PR_FGD
        frame = np.zeros((hh, ww), bool)
        frame[[0, -1], :] = True
        frame[:, [0, -1]] = True
        gc[frame & region] = cv2.GC_PR_BGD
        gc[sure_bg & ~seeds] = cv2.GC_BGD
        gc[seeds] = cv2.GC_FGD
        gc[neg_disk] = cv2.GC_BGD
        return gc

    def _edge_strength(self, st: Any, k: int) -> np.ndarray:
        """Per-pixel depth-edge strength for granularity ``k`` (≥ 1: an edge), cached per view."""
        cache = st["strength"]
        if k not in cache:
            cfg = self.config
            jpix, cpix = st["edges"]
            jt = cfg.jump_tol[k]
            kernel = np.ones((2 * cfg.crease_gate_px + 1,) * 2, np.uint8)
            near_jump = cv2.dilate((jpix > cfg.crease_gate * jt).astype(np.uint8), kernel).astype(
                bool
            )
            cache[k] = np.maximum(jpix / jt, np.where(near_jump, 0.0, cpix / cfg.crease_tol[k]))
        return cache[k]

    def _edge_labels(
        self,
        st: Any,
        k: int,
        sure_bg: np.ndarray,
        seeds: np.ndarray,
        neg_disk: np.ndarray,
        nearer_neg: np.ndarray,
        pr: np.ndarray,
        pc: np.ndarray,
        nr: np.ndarray,
        nc: np.ndarray,
    ) -> tuple[np.ndarray, float]:
        """GrabCut's initial labels from the depth-edge region (module docstring) and the
        region's closure (fraction of its outer rim on a depth edge)."""
        cfg = self.config
        strength = self._edge_strength(st, k)
        hh, ww = strength.shape
        free = strength < 1.0
        core = _components_with(free, pr, pc, connectivity=4)
        core[pr, pc] = True
        region = de.regrow(core, st["logd"], ~free, cfg.jump_tol[k], cfg.regrow_px)
        if len(nr) and region[nr, nc].any():  # a negative inside: drop its edge-free part
            region &= ~_components_with(free & region, nr, nc, connectivity=4)
        fg = (region & ~nearer_neg & _components_with(~sure_bg, pr, pc)) | seeds
        rim = cv2.dilate(fg.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~fg
        closure = float((strength[rim] >= 1.0).mean()) if rim.any() else 1.0
        gc = np.full((hh, ww), cv2.GC_PR_BGD, np.uint8)
        gc[sure_bg & ~region] = cv2.GC_BGD
        gc[fg] = cv2.GC_PR_FGD
        frame = np.zeros((hh, ww), bool)
        frame[[0, -1], :] = True
        frame[:, [0, -1]] = True
        gc[frame & fg] = cv2.GC_PR_BGD
        gc[seeds] = cv2.GC_FGD
        gc[neg_disk] = cv2.GC_BGD
        return gc, closure

    def _grabcut(
        self,
        feat8: np.ndarray,
        init: np.ndarray,
        pr: np.ndarray,
        pc: np.ndarray,
        nr: np.ndarray,
        nc: np.ndarray,
        iters: int,
        scale: float,
    ) -> np.ndarray:
        """Seeded GrabCut in an ROI around the probable foreground → binary mask."""
        cfg = self.config
        hh, ww = init.shape
        ys, xs = np.nonzero((init == cv2.GC_PR_FGD) | (init == cv2.GC_FGD))
        m = int(round(cfg.roi_margin * max(hh, ww))) + 2
        y0, y1 = max(ys.min() - m, 0), min(ys.max() + m + 1, hh)
        x0, x1 = max(xs.min() - m, 0), min(xs.max() + m + 1, ww)
        sub, img = init[y0:y1, x0:x1].copy(), feat8[y0:y1, x0:x1]
        sh, sw = sub.shape
        if scale < 1.0:  # coarser cut: resample features/labels, re-plant the clicks
            ch, cw = max(2, int(round(sh * scale))), max(2, int(round(sw * scale)))
            img = cv2.resize(img, (cw, ch), interpolation=cv2.INTER_AREA)
            sub = cv2.resize(sub, (cw, ch), interpolation=cv2.INTER_NEAREST)
            for rr, cc, lab in ((pr, pc, cv2.GC_FGD), (nr, nc, cv2.GC_BGD)):
                ry = np.clip(((rr - y0 + 0.5) * ch / sh).astype(int), 0, ch - 1)
                rx = np.clip(((cc - x0 + 0.5) * cw / sw).astype(int), 0, cw - 1)
                sub[ry, rx] = lab
        is_fg = (sub == cv2.GC_FGD) | (sub == cv2.GC_PR_FGD)
        if is_fg.sum() >= 8 and (~is_fg).sum() >= 8:
            cv2.setRNGSeed(cfg.seed)
            bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
            try:
                cv2.grabCut(
                    np.ascontiguousarray(img),
                    sub,
                    None,
                    bgd,
                    fgd,
                    max(1, int(iters)),
                    cv2.GC_INIT_WITH_MASK,
                )
                is_fg = (sub == cv2.GC_FGD) | (sub == cv2.GC_PR_FGD)
            except cv2.error:  # degenerate colour models: keep the initial labelling
                pass
        if is_fg.shape != (sh, sw):
            is_fg = cv2.resize(
                is_fg.astype(np.uint8), (sw, sh), interpolation=cv2.INTER_NEAREST
            ).astype(bool)
        out = np.zeros((hh, ww), bool)
        out[y0:y1, x0:x1] = is_fg
        return _components_with(out, pr, pc)

    def _soften(self, binary: np.ndarray, full: tuple[int, int]) -> np.ndarray:
        h, w = full
        hh, ww = binary.shape
        if not binary.any():
            return np.zeros((h, w), np.float32)
        b = binary.astype(np.uint8)
        d_in = cv2.distanceTransform(b, cv2.DIST_L2, 5)
        d_out = cv2.distanceTransform(1 - b, cv2.DIST_L2, 5)
        sd = np.where(binary, np.minimum(d_in, 1e4) - 0.5, 0.5 - np.minimum(d_out, 1e4))
        sd = sd.astype(np.float32)
        if (hh, ww) != (h, w):
            sd = cv2.resize(sd, (w, h), interpolation=cv2.INTER_LINEAR) * np.float32(w / ww)
        return sigmoid(sd / np.float32(self.config.softness_px))

    def _score(
        self,
        binary: np.ndarray,
        feat: np.ndarray,
        pr: np.ndarray,
        pc: np.ndarray,
        nr: np.ndarray,
        nc: np.ndarray,
    ) -> float:
        cfg = self.config
        area = binary.mean()
        if area == 0 or area > cfg.max_area_frac:
            return 0.0
        size = min(1.0, area / cfg.min_area_frac)
        k = np.ones((3, 3), np.uint8)
        b8 = binary.astype(np.uint8)
        ring_in = binary & ~cv2.erode(b8, k, iterations=2, borderType=cv2.BORDER_REPLICATE).astype(
            bool
        )
        ring_out = cv2.dilate(b8, k, iterations=2).astype(bool) & ~binary
        if not ring_out.any():
            return 0.0
        fi, fo = feat[ring_in], feat[ring_out]
        d2 = np.sum((fi.mean(0) - fo.mean(0)) ** 2 / (fi.var(0) + fo.var(0) + cfg.sep_floor**2))
        sep = d2 / (1.0 + d2)
        cover = binary[pr, pc].mean()
        neg_in = binary[nr, nc].mean() if len(nr) else 0.0
        return float(sep * size * cover * (1.0 - neg_in))

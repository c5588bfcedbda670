"""2DGS centroid view (paper App. C.3, alg:centroid-gs).

Strategy 1 (physical neighbourhood): z = D_med at the click, x_w its back-projection,
R_phys = p_f z tan(FOV_x/2) (eq:Rphys); N = opaque surfels within R_phys of x_w (eq:neigh),
found by a distance pass over the opaque centres of an x slab (sorted by x, float64: the same
set as a k-d tree, without building one per scene). |N| < 5 → r_init = z p_f and no box; else
R_lat = P90 of the perpendicular offsets (eq:Rlat), r_init = R_lat / (f_fill tan(FOV_x/2))
(eq:Rinit). Strategy 2 (occlusion-aware refinement): K_r radii linspace(r_init, 0.3 r_init),
each probe's central patch depth read against τ_occ (eq:tauocc); the first r_k with
O(r_k) < τ_O (eq:occfrac) is taken, else the smallest. Beyond the paper
(``ViewConfig.probe_full_first``): r_0 is tested on the full-resolution render the view needs
anyway, so an accepted first candidate costs one render. Details: docs/design-notes.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from ..camera import Camera
from ..render.buffers import RenderBuffers
from ..scene import SurfelScene
from .centroid_common import CentroidView, ProbeRecord, build_pose, click_point
from .config import ViewConfig

__all__ = ["GsCentroidPlanner", "central_patch", "occluded_fraction"]


def central_patch(h: int, w: int, f_fill: float) -> tuple[slice, slice]:
    """Rows/columns of the centred patch covering ``f_fill`` of each image side."""
    ph, pw = max(1, round(h * f_fill)), max(1, round(w * f_fill))
    r0, c0 = (h - ph) // 2, (w - pw) // 2
    return slice(r0, r0 + ph), slice(c0, c0 + pw)


def occluded_fraction(d_med: np.ndarray, tau_occ: float, f_fill: float) -> tuple[float, int]:
    """eq:occfrac over the central patch: (O, number of valid patch pixels)."""
    rs, cs = central_patch(*d_med.shape, f_fill)
    d = d_med[rs, cs]
    d = d[np.isfinite(d) & (d > 0.0)]
    if d.size == 0:
        return float("nan"), 0
    return float(np.count_nonzero(d < tau_occ) / d.size), int(d.size)


def _row_norms(cols: np.ndarray, rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(cols[:, rows].T - x, axis=1)`` bit for bit (``cols`` ``[3, n]``) —
    NumPy sums the squares of a row left to right, ``(dx² + dy²) + dz²`` — from the three
    coordinate rows instead of a gathered ``[n,3]`` block and a length-3 reduction
    (no ``[n,3]`` gather on the click's eq:neigh path)."""
    dx, dy, dz = (cols[k, rows] - x[k] for k in range(3))
    return np.sqrt(dx * dx + dy * dy + dz * dz)


def _lateral_distances(mu: np.ndarray, x_w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """eq:Rlat's ``‖r⊥‖`` per centre, ``r = μ − x_w``, ``r⊥ = r − (r·v) v``: bit for bit
    ``np.linalg.norm(r - np.outer(r @ v, v), axis=1)`` (the same products, NumPy's row
    order of the squares) from columns, without the ``[n,3]`` temporaries."""
    r = mu - x_w
    a = r @ v
    px, py, pz = (r[:, k] - a * v[k] for k in range(3))
    return np.sqrt(px * px + py * py + pz * pz)


def _probe_depth(renderer, cam: Camera, scale: float, f_fill: float) -> np.ndarray:
    """D_med of a probe, read only over its central patch (eq:occfrac): the renderer's
    depth-only pass of that pixel window when it has one (no SH colours, no feature
    compositing, the surfels that miss the patch culled; the patch's depths are the
    whole render's bit for bit), else a full render."""
    probe = cam if scale == 1.0 else cam.scaled(scale)
    rs, cs = central_patch(probe.height, probe.width, f_fill)
    return renderer.render_depth(probe, window=(cs.start, rs.start, cs.stop, rs.stop)).D_med


class GsCentroidPlanner:
    """Centroid views of one 2DGS scene.

    Args:
        scene: the surfel scene (its opacities and centres feed eq:neigh).
        renderer: a 2DGS renderer of the same scene (``render(camera, scale)``).
        config: :class:`ViewConfig`.

    The float64 opaque surfel centres, sorted by x, are gathered on first use and kept
    coordinate by coordinate (``[3, M]``: the x row is the sorted search key, the y and z
    rows are read contiguously by the slab test), with their surfel indices.
    """

    def __init__(self, scene: SurfelScene, renderer, config: ViewConfig | None = None):
        self.scene = scene
        self.renderer = renderer
        self.config = config or ViewConfig()
        self._opaque: np.ndarray | None = None
        self._cols: np.ndarray | None = None

    def _opaque_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """``(surfel indices [M], float64 centres [3, M])`` of the opaque surfels, by x.
        Indices are int32 when they fit (half the memory of an int64 index; no separate
        x copy)."""
        if self._cols is None:
            opaque = np.flatnonzero(self.scene.opacities > self.config.alpha_min)
            if len(self.scene.opacities) <= np.iinfo(np.int32).max:
                opaque = opaque.astype(np.int32)
            means = self.scene.means
            by_x = np.argsort(np.asarray(means[opaque, 0], np.float64), kind="stable")
            opaque = opaque[by_x]
            cols = np.empty((3, len(opaque)), np.float64)
            for k in range(3):
                cols[k] = means[opaque, k]
            self._opaque, self._cols = opaque, cols
        return self._opaque, self._cols

    def neighbourhood(self, x_w: np.ndarray, radius: float) -> np.ndarray:
        """Surfel indices of eq:neigh (opaque centres strictly within ``radius`` of ``x_w``),
        ascending."""
        return self._neighbours(x_w, radius)[0]

    def _neighbours(
        self, x_w: np.ndarray, radius: float, ordered: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`neighbourhood` (int64) and its float64 centres ``[n, 3]`` (rows in the
        same order; from the kept copies, so no second gather from the scene).
        ``ordered=False``: the same rows in the index's own order (the click reads only
        |N| and order-free statistics of the centres: no sort)."""
        opaque, cols = self._opaque_centres()
        x = np.asarray(x_w, dtype=np.float64)
        slab = abs(float(radius)) * (1.0 + 1e-9) + 1e-300
        lo = np.searchsorted(cols[0], x[0] - slab, side="left")
        hi = np.searchsorted(cols[0], x[0] + slab, side="right")
        c = cols[:, lo:hi]
        # the y/z slabs first (a centre within the ball is within them), the norm on the
        # rest: the same rows, each row's norm computed alone
        near = np.flatnonzero((np.abs(c[1] - x[1]) <= slab) & (np.abs(c[2] - x[2]) <= slab))
        d = _row_norms(c, near, x)
        rows = near[d < radius]
        idx = opaque[lo:hi][rows].astype(np.int64)
        if ordered:
            order = np.argsort(idx)
            idx, rows = idx[order], rows[order]
        return idx, np.ascontiguousarray(c[:, rows].T)

    def probe_scale(self, cam: Camera) -> float:
        cfg = self.config
        return max(cfg.probe_scale, cfg.probe_min_size / cam.width, cfg.probe_min_size / cam.height)

    def centroid_view(
        self,
        anchor: Camera,
        click,
        buffers: RenderBuffers | None = None,
        *,
        name: str = "",
        on_camera: Callable[[Camera], None] | None = None,
        depth: float | None = None,
    ) -> CentroidView:
        """alg:centroid-gs for one click (continuous pixel point) on ``anchor``.

        ``buffers``: the anchor's full-resolution render (rendered here when None).
        ``on_camera``: called with a candidate view camera before its full-resolution
        render starts — the first radius's (``probe_full_first``), then, when that one is
        rejected, the final camera before returning (the caller renders it) — so work
        that needs only the view's camera runs while the view renders (graph3d's
        masks). A rejected first candidate only wastes that work. ``depth``: the click's
        depth when the caller chose it (:func:`~.centroid_common.click_point`).

        Raises:
            DivasInputError: no surface under the click.
        """
        cfg = self.config
        if buffers is None:
            buffers = self.renderer.render(anchor)
        z, x_w = click_point(
            anchor, click, buffers.D_med, buffers.alpha, cfg.min_alpha_click, depth
        )
        v = x_w - anchor.center
        v /= np.linalg.norm(v)
        tan_half = math.tan(anchor.fov_x / 2.0)
        # Strategy 1
        r_phys = cfg.p_f * z * tan_half
        # mu: float64 centres of N; only |N|, a percentile, min/max and a min read them,
        # so their order is free (no sort)
        nb, mu = self._neighbours(x_w, r_phys, ordered=False)
        box = None
        if len(nb) < cfg.min_neighbours:
            r_init, s1 = z * cfg.p_f, "sparse"
        else:
            r_lat = float(np.percentile(_lateral_distances(mu, x_w, v), cfg.lat_percentile))
            r_init, s1 = r_lat / (cfg.f_fill * tan_half), "dense"
            uv, zz = anchor.project(mu)
            uv = uv[zz > 0]
            if len(uv):
                x0, y0 = np.clip(uv.min(0), 0, [anchor.width, anchor.height])
                x1, y1 = np.clip(uv.max(0), 0, [anchor.width, anchor.height])
                box = (float(x0), float(y0), float(x1), float(y1))
        # Strategy 2
        radii = np.linspace(r_init, cfg.probe_min_frac * r_init, cfg.n_probes)
        s = self.probe_scale(anchor)
        probes: list[ProbeRecord] = []
        r_star, accepted = float(radii[-1]), False
        full: RenderBuffers | None = None
        t_render = 0.0
        for k, r_k in enumerate(radii):
            if k == 0 and cfg.probe_full_first:
                cam = build_pose(anchor, x_w, v, float(r_k), name, cfg.near_fraction)
                if on_camera is not None:
                    on_camera(cam)
                t_render = time.perf_counter()
                full = self.renderer.render(cam)
                t_render = time.perf_counter() - t_render
                d_med = full.D_med
            else:
                cam = build_pose(anchor, x_w, v, float(r_k), near_fraction=cfg.near_fraction)
                d_med = _probe_depth(self.renderer, cam, s, cfg.f_fill)
            o, valid = occluded_fraction(d_med, 0.0, cfg.f_fill)  # validity only
            if valid == 0:
                probes.append(
                    ProbeRecord(float(r_k), float("nan"), float("nan"), 0, float("nan"), False)
                )
                continue
            zc = cam.world_to_camera(mu)[:, 2] if len(mu) else np.empty(0)
            zc = zc[zc > 0]
            if zc.size:
                z_near = float(zc.min())
                tau = cfg.tau_occ_factor * z_near
            else:
                z_near, tau = float("nan"), cfg.tau_occ_fallback * float(r_k)
            o, valid = occluded_fraction(d_med, tau, cfg.f_fill)
            ok = o < cfg.tau_o
            probes.append(ProbeRecord(float(r_k), tau, o, valid, z_near, bool(ok)))
            if ok:
                r_star, accepted = float(r_k), True
                break
        if full is not None and not (accepted and r_star == float(radii[0])):
            self.renderer.release(full.camera)  # the first candidate's render is not the view's
            full = None
        if full is not None:
            cam = full.camera
        else:
            cam = build_pose(anchor, x_w, v, r_star, name, cfg.near_fraction)
            if on_camera is not None:
                on_camera(cam)
        return CentroidView(
            cam,
            r_star,
            x_w,
            (float(click[0]), float(click[1])),
            z,
            box,
            f"{s1}+{'probe' if accepted else 'fallback'}",
            float(r_init),
            int(len(nb)),
            probes,
            _buffers=full,
            _render_s=t_render,
        )

"""Which surfels can touch a render of a few: a block index over a surfel scene.

A value render whose values are zero off a few surfels ``K`` (a selection's mask) is
decided by ``K`` and by what blends before them: a pixel's composite is the front-to-back
sum ``Σ α_i T_i v_i`` in ascending centre depth (ties by index), and every surfel behind
the deepest of ``K`` adds ``0 · w`` — nothing. So a surfel whose footprint meets only
pixels where it lies behind every surfel of ``K`` there changes nothing, and the render of
the others, in the scene's order, is the full render bit for bit
(:meth:`~.surfel_renderer.SurfelRenderer.render_values_sparse`).

Those surfels are found without a pass over the scene: the scene is cut once into blocks
of a coarse grid (surfels sorted by block), each block a ball (its members' centres and
their footprints: radius ``ρ_i = sqrt(ρ_cut,i) · max(s_1, s_2)``, the cutoff disc); a
block is kept when its ball can lie in front of the deepest surfel of ``K`` whose footprint
meets a tile (8 px) its own screen bound (:func:`ball_pixel_bounds`) meets. A kept block
is kept whole (a superset is exact: its extra surfels are behind ``K`` or off it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera

__all__ = ["WHOLE", "SurfelBlocks", "ball_pixel_bounds", "screen_box"]

_BLOCKS_PER_SIDE = 64
_CHUNK = 1 << 18  # surfels per chunk of the index's per-surfel passes
_REACH_CLASSES = 4  # footprint classes: ≤ 4×, ≤ 16×, ≤ 64×, more than the median's
_TILE = 8  # pixels per side of the depth map's tiles
#: rows of ``near``'s points per (item, tile) pass: the pairs of large footprints run to
#: tens of millions at millions of surfels; a max per tile over blocks of rows is the same
#: map, and 8192 rows keep each pass's pair arrays small enough to come from the heap's
#: free memory instead of fresh pages
_NEAR_CHUNK = 1 << 13
#: rows per pass of :func:`ball_pixel_bounds` and the depths of ``near``: its dozen
#: per-row temporaries stay small enough to come from the heap's free memory, not from
#: fresh mappings whose pages fault in (Blender's heap maps every allocation over a fixed
#: threshold anew); row by row the same arithmetic
_BOUNDS_CHUNK = 1 << 15


def ball_pixel_bounds(
    camera: Camera, centres: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous pixel bounds of balls ``centres [N,3] ± radii [N]`` in ``camera``:
    ``lo [N,2]``, ``hi [N,2]`` (meaningful where ``front``), ``front`` (the ball lies
    wholly beyond the camera plane), ``cut`` (it reaches the plane: no finite bound).
    The ball lies in its box ``p ± ρ`` (camera frame); ``u = c_x + f_x x / z`` is extreme
    over the box at its corners ``x = X ± ρ``, ``z = Z ± ρ`` when ``Z − ρ > 0``."""
    n = len(centres)
    if n <= _BOUNDS_CHUNK:
        return _ball_pixel_bounds(camera, centres, radii)
    rho = np.broadcast_to(np.asarray(radii, np.float64), (n,))
    lo, hi = np.empty((n, 2)), np.empty((n, 2))
    front, cut = np.empty(n, bool), np.empty(n, bool)
    for s in range(0, n, _BOUNDS_CHUNK):
        sl = slice(s, s + _BOUNDS_CHUNK)
        lo[sl], hi[sl], front[sl], cut[sl] = _ball_pixel_bounds(camera, centres[sl], rho[sl])
    return lo, hi, front, cut


def _ball_pixel_bounds(camera: Camera, centres: np.ndarray, radii: np.ndarray):
    """:func:`ball_pixel_bounds` of one block of rows."""
    pc = camera.world_to_camera(centres)
    rho = np.asarray(radii, np.float64)
    z_lo, z_hi = pc[:, 2] - rho, pc[:, 2] + rho
    front = z_lo > 0.0
    cut = (z_lo <= 0.0) & (z_hi > 0.0)
    zl = np.where(front, z_lo, 1.0)
    zh = np.where(front, z_hi, 1.0)
    lo, hi = np.empty((len(pc), 2)), np.empty((len(pc), 2))
    for k, (f, c) in enumerate(((camera.fx, camera.cx), (camera.fy, camera.cy))):
        a, b = pc[:, k] - rho, pc[:, k] + rho
        lo[:, k] = c + f * np.minimum(a / zl, a / zh)
        hi[:, k] = c + f * np.maximum(b / zl, b / zh)
    return lo, hi, front, cut


#: a window that is the whole image (:func:`screen_box`)
WHOLE = "whole"


def screen_box(
    camera: Camera, points: np.ndarray, reach: np.ndarray, margin: float
) -> tuple[int, int, int, int] | str | None:
    """Pixel window ``(x0, y0, x1, y1)`` (``x1``, ``y1`` exclusive, clipped to the image)
    that holds every pixel the balls ``points [N,3] ± reach [N]`` can reach in
    ``camera``, their :func:`ball_pixel_bounds` widened by ``margin`` pixels (the
    renderer's screen-space low-pass and rounding); :data:`WHOLE` when a ball reaches the
    camera plane; None when nothing can show (no ball in front of the camera, or all
    beyond the image)."""
    if len(points) == 0:
        return None
    lo_px, hi_px, front, cut = ball_pixel_bounds(camera, points, reach)
    if cut.any():
        return WHOLE
    if not front.any():
        return None
    lo = lo_px[front].min(axis=0) - margin
    hi = hi_px[front].max(axis=0) + margin
    x0 = max(0, int(np.floor(lo[0])))
    y0 = max(0, int(np.floor(lo[1])))
    x1 = min(camera.width, int(np.floor(hi[0])) + 1)
    y1 = min(camera.height, int(np.floor(hi[1])) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, y0, x1, y1


@dataclass(eq=False)
class SurfelBlocks:
    """A scene's surfels grouped by the cells of a coarse grid (module docstring).

    Attributes:
        order: ``[N]`` surfel rows sorted by block; start: ``[B+1]`` each block's slice.
        centre, radius: ``[B,3]``, ``[B]`` each block's ball (centres and footprints).
        block: ``[N]`` int32, each surfel's block (None: not built).
    """

    order: np.ndarray
    start: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    block: np.ndarray | None = None

    @classmethod
    def build(cls, means: np.ndarray, reach: np.ndarray) -> SurfelBlocks:
        """Blocks of ``means [N,3]`` with footprint radii ``reach [N]``."""
        m = np.asarray(means)
        n = len(m)
        if n == 0:
            z = np.zeros(0)
            return cls(np.zeros(0, np.int64), np.zeros(1, np.int64), z.reshape(0, 3), z)
        g = _BLOCKS_PER_SIDE
        # cells cut at each axis's quantiles (a dense object inside a large backdrop gets
        # many small blocks), and split by footprint class (a few huge backdrop surfels
        # would otherwise widen the balls of the blocks they share with small ones).
        # Per axis and in chunks: the transient memory stays a few [N] arrays
        q = np.linspace(0.0, 1.0, g + 1)[1:-1]
        key = np.zeros(n, np.int64)
        for k in (2, 1, 0):
            x = m[:, k].astype(np.float64)
            key *= g
            key += np.searchsorted(np.quantile(x, q), x, side="right")
        del x
        r = np.asarray(reach, np.float64)
        pos = r > 0
        med = float(np.median(r[pos])) if np.any(pos) else 1.0
        del pos
        for c in range(0, n, _CHUNK):
            rc = r[c : c + _CHUNK]
            with np.errstate(divide="ignore"):
                cl = np.clip(
                    np.floor(np.log2(np.maximum(rc, 1e-300) / med) / 2), 0, _REACH_CLASSES - 1
                )
            key[c : c + _CHUNK] += g**3 * cl.astype(np.int64)
        order = np.argsort(key, kind="stable")
        key = key[order]
        first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        del key
        start = np.r_[first, n].astype(np.int64)
        blk = np.repeat(np.arange(len(first), dtype=np.int32), np.diff(start))
        centre = np.empty((len(first), 3))
        scale = 1.0
        for k in range(3):
            x = m[order, k].astype(np.float64)
            centre[:, k] = 0.5 * (np.minimum.reduceat(x, first) + np.maximum.reduceat(x, first))
            scale = max(scale, float(np.abs(x).max()) + 1.0)
        del x
        val = np.empty(n)
        for c in range(0, n, _CHUNK):
            o = order[c : c + _CHUNK]
            d = m[o].astype(np.float64) - centre[blk[c : c + _CHUNK]]
            val[c : c + _CHUNK] = np.linalg.norm(d, axis=1) + r[o]
        far = np.maximum.reduceat(val, first)
        del val, d
        # float32 positions and rounding: a relative and an absolute sliver
        radius = far * (1.0 + 1e-4) + 1e-5 * scale
        block = np.empty(len(order), np.int32)
        block[order] = blk
        return cls(order.astype(np.int64), start, centre, radius, block)

    def in_window(
        self, camera: Camera, window: tuple[int, int, int, int], margin_px: float
    ) -> np.ndarray:
        """Ascending rows of the surfels of every block whose ball can reach a pixel of
        ``window`` (``x0, y0, x1, y1`` half-open pixels of ``camera``'s image) — a
        superset of the surfels a render of that window does not cull (a zoomed
        centroid view or a probe's central patch meets a few blocks, and only
        their surfels need projecting). A ball wholly behind the camera plane is left
        out (its surfels lie behind the near plane); one reaching the plane is kept.
        Bounds are widened by ``margin_px`` (the low-pass disc), a pixel of rounding and
        the rasterizer's slivers."""
        lo, hi, front, cut = ball_pixel_bounds(camera, self.centre, self.radius)
        m = margin_px + 2e-4 * (np.abs(lo) + np.abs(hi))
        a, b = lo - m, hi + m
        x0, y0, x1, y1 = window
        on = front & (b[:, 0] >= x0 - 1) & (a[:, 0] <= x1 + 1)
        on &= (b[:, 1] >= y0 - 1) & (a[:, 1] <= y1 + 1)
        return self._rows(np.flatnonzero(on | cut))

    def _rows(self, keep: np.ndarray) -> np.ndarray:
        """Ascending rows of the surfels of the blocks ``keep`` (block indices)."""
        if self.block is None or len(keep) < 64:
            parts = [self.order[self.start[k] : self.start[k + 1]] for k in keep]
            return np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
        mask = np.zeros(len(self.start) - 1, bool)
        mask[keep] = True
        return np.flatnonzero(mask[self.block])

    def near(
        self, camera: Camera, points: np.ndarray, reach: np.ndarray, margin_px: float
    ) -> np.ndarray:
        """Sorted rows of the surfels of every block that can blend, somewhere in
        ``camera``'s image, before one of the surfels at ``points [K,3]`` (footprint radii
        ``reach [K]``): a superset of what their value render needs. Per tile of
        ``_TILE`` px the deepest of those surfels whose footprint bound meets it; a block
        is kept when its ball can lie in front of that depth in a tile its bound meets
        (bounds widened by ``margin_px`` and the rasterizer's slivers)."""
        tiles_x = -(-camera.width // _TILE)
        tiles_y = -(-camera.height // _TILE)
        zmap = np.full(tiles_x * tiles_y, -np.inf)
        lo, hi, front, cut = ball_pixel_bounds(camera, points, reach)
        z = np.empty(len(points))
        for s in range(0, len(z), _BOUNDS_CHUNK):  # small temporaries (_BOUNDS_CHUNK)
            z[s : s + _BOUNDS_CHUNK] = camera.world_to_camera(points[s : s + _BOUNDS_CHUNK])[:, 2]
        if np.any(cut & (z > 0.0)):
            zmap[:] = np.inf  # a footprint reaching the camera plane: no finite bound
        else:
            for s in range(0, len(z), _NEAR_CHUNK):  # the max is exact in any order
                sl = slice(s, s + _NEAR_CHUNK)
                item, tile = self._tiles(camera, lo[sl], hi[sl], front[sl], margin_px)
                np.maximum.at(zmap, tile, z[sl][item])
        if not np.any(zmap > -np.inf):  # none of them on the image
            return np.zeros(0, np.int64)
        keep = np.flatnonzero(self._needed(camera, self.centre, self.radius, zmap, margin_px))
        if len(keep) == 0:
            return np.zeros(0, np.int64)
        return self._rows(keep)

    def _needed(
        self,
        camera: Camera,
        centres: np.ndarray,
        radii: np.ndarray,
        zmap: np.ndarray,
        margin_px: float,
    ) -> np.ndarray:
        """Bool ``[N]``: the balls that can lie in front of ``zmap`` in a tile their
        screen bound meets (any, when they reach the camera plane)."""
        z_lo = camera.world_to_camera(centres)[:, 2] - radii
        lo, hi, front, cut = ball_pixel_bounds(camera, centres, radii)
        need = np.full(len(z_lo), -np.inf)
        item, tile = self._tiles(camera, lo, hi, front, margin_px)
        if len(item):
            first = np.flatnonzero(np.r_[True, item[1:] != item[:-1]])
            need[item[first]] = np.maximum.reduceat(zmap[tile], first)
        need[cut] = zmap.max()
        fin = np.isfinite(need)
        need[fin] += 1e-4 * (np.abs(need[fin]) + 1.0)  # float32 sort keys
        return z_lo <= need

    @staticmethod
    def _tiles(
        camera: Camera, lo: np.ndarray, hi: np.ndarray, front: np.ndarray, margin_px: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(item, tile)`` pairs: the tiles each bound ``lo``–``hi`` (rows where
        ``front``) meets, widened by ``margin_px`` and the rasterizer's slivers; items in
        ascending order."""
        tiles_x = -(-camera.width // _TILE)
        tiles_y = -(-camera.height // _TILE)
        m = margin_px + 2e-4 * (np.abs(lo) + np.abs(hi))
        a, b = lo - m, hi + m
        on = front & (b[:, 0] >= 0) & (a[:, 0] <= camera.width)
        on &= (b[:, 1] >= 0) & (a[:, 1] <= camera.height)
        idx = np.flatnonzero(on)
        x0 = np.clip(np.floor(a[idx, 0] / _TILE), 0, tiles_x - 1).astype(np.int64)
        x1 = np.clip(np.floor(b[idx, 0] / _TILE), 0, tiles_x - 1).astype(np.int64)
        y0 = np.clip(np.floor(a[idx, 1] / _TILE), 0, tiles_y - 1).astype(np.int64)
        y1 = np.clip(np.floor(b[idx, 1] / _TILE), 0, tiles_y - 1).astype(np.int64)
        nx = x1 - x0 + 1
        cnt = nx * (y1 - y0 + 1)
        k = np.repeat(np.arange(len(idx)), cnt)
        local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        tile = (y0[k] + local // nx[k]) * tiles_x + x0[k] + local % nx[k]
        return idx[k], tile

"""The neighbourhood cells of the 3DGS completion and its sparse per-view gather.

The completion's decision reads the contribution records ``A₁, A₀`` of two sets of Gaussians
only: those of the coarse cells near the voxel selection (:class:`CoarseCells`) and the
selected ones. :func:`sparse_contributions` runs the contribution pass on only the surfels
that can blend before one of the cover's Gaussians ``K`` somewhere in the image
(:meth:`~divas_engine.render.surfel_blocks.SurfelBlocks.near`), so the weights of ``K`` equal
the full pass's — bit for bit while the full pass walks the image in one band of tiles. Each
tile's list is walked only up to its last Gaussian of ``K``; a binning the renderer still keeps
is walked directly. A record's cover is widened when the neighbourhood outgrows it; the full
pass is used when the cover holds most of the scene, or off the CPU. Details:
docs/design-notes.md.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from divas_kernels import accumulate_contributions

from ..camera import Camera
from ..render.surfel_blocks import WHOLE, screen_box

__all__ = ["CoarseCells", "sparse_contributions", "start_gather"]


def _csr(cell_of: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Members grouped by cell: ``(order, start)`` with cell ``c``'s members
    ``order[start[c]:start[c + 1]]`` (members of the sentinel cell ``n_cells`` last)."""
    order = np.argsort(cell_of, kind="stable").astype(np.int32)
    start = np.searchsorted(cell_of[order], np.arange(n_cells + 1)).astype(np.int64)
    return order, start


def _gather(order: np.ndarray, start: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The members of ``cells`` (indices, no sentinel), concatenated: ``O(members)``."""
    lo, hi = start[cells], start[np.asarray(cells) + 1]
    ln = hi - lo
    total = int(ln.sum())
    if total == 0:
        return np.zeros(0, np.int32)
    # positions lo[c] + 0 … ln[c] − 1 for each cell, without a Python loop
    nz = ln > 0
    lo, ln = lo[nz], ln[nz]
    step = np.ones(total, np.int64)
    ends = np.cumsum(ln)
    step[0] = lo[0]
    step[ends[:-1]] = lo[1:] - (lo[:-1] + ln[:-1]) + 1
    return order[np.cumsum(step)]


class CoarseCells:
    """Coarse cells of ``2^k`` voxels holding Gaussians or active voxels, with their
    26-neighbour table and member lists (built once per scene), so the decision touches
    only the cells near the selection."""

    def __init__(self, g_coords: np.ndarray, g_valid: np.ndarray, v_coords: np.ndarray, k: int):
        # coordinates may be negative outside the grid: shift into [0, 2^21) before
        # packing three 21-bit fields (|c| < 2^20, checked by the caller; a larger
        # shift would overflow a field and alias distant cells into one key)
        off = 1 << 20

        def key(c: np.ndarray) -> np.ndarray:
            c = (c >> k) + off
            return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]

        gk = key(g_coords[g_valid])
        vk = key(v_coords)
        self.keys = np.unique(np.concatenate([gk, vk]))
        self.n = len(self.keys)
        self.of_gauss = np.full(len(g_coords), self.n, np.int64)  # n = the empty sentinel
        self.of_gauss[g_valid] = np.searchsorted(self.keys, gk)
        self.of_voxel = np.searchsorted(self.keys, vk)
        self.g_order, self.g_start = _csr(self.of_gauss, self.n)
        self.v_order, self.v_start = _csr(self.of_voxel, self.n)
        cx = (self.keys >> 42) & ((1 << 21) - 1)
        cy = (self.keys >> 21) & ((1 << 21) - 1)
        cz = self.keys & ((1 << 21) - 1)
        nb = []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    k2 = ((cx + dx) << 42) | ((cy + dy) << 21) | (cz + dz)
                    i = np.searchsorted(self.keys, k2)
                    i = np.minimum(i, self.n - 1) if self.n else i
                    hit = self.keys[i] == k2 if self.n else np.zeros(0, bool)
                    nb.append(np.where(hit, i, self.n).astype(np.int32))
        self.neighbours = np.stack(nb, axis=1) if nb else np.zeros((0, 27), np.int32)

    def dilate_into(self, near: np.ndarray, voxels: np.ndarray) -> np.ndarray:
        """Set in ``near`` (``[C+1] bool``, the last entry the always-False sentinel) the
        cells within one cell of a cell holding one of the active voxels ``voxels``
        (indices); returns the cells that were not near before:
        ``O(|voxels| + 27 · cells touched)``."""
        if len(voxels) == 0:
            return np.zeros(0, np.int64)
        return self.dilate_cells(near, self.of_voxel[voxels])

    def dilate_cells(self, near: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """:meth:`dilate_into` from cells (indices; the sentinel is ignored)."""
        # boolean marks over the C cells, not np.unique (a sort): C ≪ N
        mark = np.zeros(self.n + 1, bool)
        mark[cells] = True
        cells = np.flatnonzero(mark[: self.n])
        if len(cells) == 0:
            return np.zeros(0, np.int64)
        mark[:] = False
        mark[self.neighbours[cells].ravel()] = True
        mark[self.n] = False
        fresh = np.flatnonzero(mark & ~near)
        near[fresh] = True
        return fresh

    def voxels_in(self, cells: np.ndarray) -> np.ndarray:
        return _gather(self.v_order, self.v_start, cells)

    def gaussians_in(self, cells: np.ndarray) -> np.ndarray:
        return _gather(self.g_order, self.g_start, cells)

    def rings(self, cells: np.ndarray, r: int) -> np.ndarray:
        """``[C+1] bool``: the cells within ``r`` cells (Chebyshev, through the neighbour
        table) of ``cells`` (indices; the sentinel is ignored)."""
        out = np.zeros(self.n + 1, bool)
        cells = np.asarray(cells, np.int64)
        out[cells] = True
        out[self.n] = False
        fresh = np.flatnonzero(out)
        for _ in range(r):
            if len(fresh) == 0:
                break
            fresh = self.dilate_cells(out, fresh)
        return out

    def members(self, cover: np.ndarray, sentinel: bool = True) -> np.ndarray:
        """The Gaussians of the cells set in ``cover`` (``[C+1] bool``) and, with
        ``sentinel``, those of the sentinel (no finite cell: never in the
        neighbourhood, read only when selected)."""
        g = self.gaussians_in(np.flatnonzero(cover[: self.n]))
        if not sentinel:
            return g
        return np.concatenate([g, self.g_order[self.g_start[self.n] :]])


def sparse_contributions(
    renderer, camera: Camera, positive: np.ndarray, rows: np.ndarray, max_fraction: float
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """``(A₁, A₀, surfels)`` ``[len(rows)]`` float32 of the Gaussians ``rows`` (distinct)
    in ``camera`` split by the ``[H,W]`` bool mask ``positive`` — equal to those of the
    full pass (:meth:`~divas_engine.render.surfel_renderer.SurfelRenderer.contributions`).

    When the renderer keeps the view's binning (the session's accept: the view was just
    rendered), that binning's tile lists are walked, each only up to its last Gaussian of
    ``rows`` (``accumulate_contributions(targets=…)``: nothing is projected, sorted or
    binned, and every Gaussian of ``rows`` sees what the full pass's walk gave it);
    ``surfels`` is then the scene's size. Else the pass runs over only the surfels that
    can blend before one of ``rows`` (module docstring; ``surfels`` the size of that
    sub-scene), in the window their footprints reach, also cut after each tile's last
    target. None when that sub-scene holds more than ``max_fraction`` of the scene or the
    renderer is not on the CPU: the full pass is cheaper there."""
    buf = renderer.surfel_buffers
    n = len(buf)
    rows = np.asarray(rows, np.int64)
    if not buf.device.is_cpu or not renderer.renders_sparse:
        return None
    a1 = np.zeros(len(rows), np.float32)
    a0 = np.zeros(len(rows), np.float32)
    if len(rows) == 0:
        return a1, a0, 0
    view = (camera.w2c, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    settings = renderer.config.raster_settings(camera)
    kept = renderer.kept_binning(camera)
    if kept is not None and kept.bands is not None:
        order = np.argsort(rows)
        out = accumulate_contributions(
            buf, *view, positive, settings, binning=kept, targets=rows[order]
        )
        a1[order] = out.a1.numpy()
        a0[order] = out.a0.numpy()
        return a1, a0, n
    blocks, reach = renderer.sparse_index()  # sets the screen margin of the bounds
    means = buf.means.numpy()
    sub = blocks.near(camera, means[rows], reach[rows], renderer._margin_px)
    if len(sub) > max_fraction * n:
        return None
    if len(sub) == 0:
        return a1, a0, 0
    # only the pixels the footprints of ``rows`` can reach are walked (the window holds
    # each of them whole, so their A₀ too): the tiles the surfels in front spill over
    # elsewhere are skipped
    box = screen_box(camera, means[rows], reach[rows], renderer._margin_px + 2.0)
    if box is None:  # none of them can show
        return a1, a0, 0
    # a Gaussian of ``rows`` outside the sub-scene does not reach the image: weight 0
    pos = np.minimum(np.searchsorted(sub, rows), len(sub) - 1)
    hit = sub[pos] == rows
    hit = np.flatnonzero(hit)
    hit = hit[np.argsort(pos[hit])]  # targets ascending
    out = accumulate_contributions(
        buf,
        *view,
        positive,
        settings,
        window=None if box == WHOLE else box,
        rows=sub,
        targets=pos[hit],
    )
    a1[hit] = out.a1.numpy()
    a0[hit] = out.a0.numpy()
    return a1, a0, len(sub)


# one background thread for the gathers (its walk runs on the launch pool's threads), so
# the completion makes what does not read the walk meanwhile (off the per-update path);
# a forked child starts its own
_GATHER: ThreadPoolExecutor | None = None


def _forget_gather_thread() -> None:
    global _GATHER
    _GATHER = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_gather_thread)


def start_gather(
    renderer, camera: Camera, positive: np.ndarray, rows: np.ndarray, max_fraction: float
) -> Future:
    """:func:`sparse_contributions` started in a background thread: its future (the
    caller must not change ``positive`` / ``rows`` until it is done)."""
    global _GATHER
    if _GATHER is None:
        _GATHER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="divas-gather")
    return _GATHER.submit(sparse_contributions, renderer, camera, positive, rows, max_fraction)

"""Nested density-grid cascades in Morton order (instant-ngp, torch-ngp) ↔ one lattice.

Both tools keep ``C`` cascades of ``R³`` cells (``R = 128``), each flattened in Morton order
with ``x`` in bit 0, ``y`` in bit 1, ``z`` in bit 2 (instant-ngp ``tiny-cuda-nn/common_device.h``
``morton3D``; torch-ngp ``raymarching.cu`` ``__morton3D``). Cascade ``m`` is the box
``centre ± half_m`` with ``half_m = min(half0 · 2^m, cap)``; cell ``i`` of an axis covers
``[lo + i·h, lo + (i+1)·h)`` with ``h = 2·half_m / R``. A point is looked up in the finest
cascade containing it. :func:`merge_cascades` resamples them onto one lattice at the cell size
of one cascade over the box of the occupied cells: finer cascades are mean-pooled into it,
coarser ones sampled at its cell centres, finer ones overwriting coarser ones as a lookup
would. :func:`cascade_mask` maps a selection on that lattice back to the raw cells (a raw cell
is kept when a selected lattice cell overlaps it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "CascadeLayout",
    "LatticeBox",
    "morton3d",
    "morton3d_invert",
    "morton_to_dense",
    "dense_to_morton",
    "merge_cascades",
    "cascade_mask",
]


def _expand_bits(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.uint64) & np.uint64(0x3FF)
    v = (v * np.uint64(0x00010001)) & np.uint64(0xFF0000FF)
    v = (v * np.uint64(0x00000101)) & np.uint64(0x0F00F00F)
    v = (v * np.uint64(0x00000011)) & np.uint64(0xC30C30C3)
    v = (v * np.uint64(0x00000005)) & np.uint64(0x49249249)
    return v


def morton3d(x, y, z) -> np.ndarray:
    """Morton code of integer cell coordinates (each < 1024): ``x`` in bit 0."""
    code = _expand_bits(x) | (_expand_bits(y) << np.uint64(1)) | (_expand_bits(z) << np.uint64(2))
    return code.astype(np.int64)


def morton3d_invert(code) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, y, z)`` of Morton codes (the inverse of :func:`morton3d`)."""
    c = np.asarray(code, np.uint64)

    def compact(v):
        v = v & np.uint64(0x49249249)
        v = (v | (v >> np.uint64(2))) & np.uint64(0xC30C30C3)
        v = (v | (v >> np.uint64(4))) & np.uint64(0x0F00F00F)
        v = (v | (v >> np.uint64(8))) & np.uint64(0xFF0000FF)
        v = (v | (v >> np.uint64(16))) & np.uint64(0x0000FFFF)
        return v.astype(np.int64)

    return compact(c), compact(c >> np.uint64(1)), compact(c >> np.uint64(2))


_PERM: dict[int, np.ndarray] = {}


def _dense_order(res: int) -> np.ndarray:
    """Morton code of every cell of an ``res³`` block, indexed ``[x, y, z]`` (flattened)."""
    if res not in _PERM:
        i = np.arange(res)
        x, y, z = np.meshgrid(i, i, i, indexing="ij")
        _PERM[res] = morton3d(x.ravel(), y.ravel(), z.ravel())
    return _PERM[res]


def morton_to_dense(flat: np.ndarray, res: int) -> np.ndarray:
    """``[C, res³]`` Morton-ordered cascades → ``[C, res, res, res]`` indexed ``[x, y, z]``."""
    flat = np.asarray(flat).reshape(-1, res**3)
    return flat[:, _dense_order(res)].reshape(-1, res, res, res)


def dense_to_morton(dense: np.ndarray) -> np.ndarray:
    """Inverse of :func:`morton_to_dense`: ``[C, res, res, res]`` → ``[C, res³]``."""
    c, res = dense.shape[0], dense.shape[1]
    out = np.empty((c, res**3), dense.dtype)
    out[:, _dense_order(res)] = dense.reshape(c, -1)
    return out


@dataclass(frozen=True)
class CascadeLayout:
    """Where the cascades lie, in the grid's own frame.

    Attributes:
        n_cascades: ``C``.
        resolution: ``R`` cells per axis of one cascade.
        centre: ``[3]`` common centre (instant-ngp 0.5, torch-ngp 0).
        half0: half-extent of cascade 0 (instant-ngp 0.5, torch-ngp 1).
        cap: largest half-extent (torch-ngp ``bound``; None: no cap).
    """

    n_cascades: int
    resolution: int
    centre: tuple[float, float, float]
    half0: float
    cap: float | None = None

    def half(self, m: int) -> float:
        h = self.half0 * 2.0**m
        return h if self.cap is None else min(h, float(self.cap))

    def cell(self, m: int) -> float:
        return 2.0 * self.half(m) / self.resolution

    def lo(self, m: int) -> np.ndarray:
        return np.asarray(self.centre, np.float64) - self.half(m)


@dataclass(frozen=True)
class LatticeBox:
    """The lattice :func:`merge_cascades` resampled onto (grid frame, axes x, y, z).

    Attributes:
        level: the cascade whose cell size the lattice has.
        lo: ``[3]`` lattice min corner; cell: cell edge; shape: ``(nx, ny, nz)``.
    """

    level: int
    lo: np.ndarray
    cell: float
    shape: tuple[int, int, int]

    @property
    def hi(self) -> np.ndarray:
        return self.lo + self.cell * np.asarray(self.shape, np.float64)


def _cell_range(lo_box: np.ndarray, hi_box: np.ndarray, box: LatticeBox):
    """Per axis, the lattice cells whose centres lie in ``[lo_box, hi_box)``."""
    first = np.ceil((lo_box - box.lo) / box.cell - 0.5 - 1e-9).astype(int)
    last = np.ceil((hi_box - box.lo) / box.cell - 0.5 - 1e-9).astype(int)
    shape = np.asarray(box.shape)
    return np.clip(first, 0, shape), np.clip(last, 0, shape)


def _pool(a: np.ndarray, f: int) -> np.ndarray:
    """Mean over ``f³`` blocks of a ``[x, y, z]`` array (sides divisible by ``f``)."""
    if f == 1:
        return a
    x, y, z = a.shape
    return a.reshape(x // f, f, y // f, f, z // f, f).mean(axis=(1, 3, 5))


def _choose_box(occupied: np.ndarray, layout: CascadeLayout, max_side: int) -> LatticeBox:
    """The finest cascade cell size at which the occupied cells' box fits ``max_side``."""
    R = layout.resolution
    lo_occ, hi_occ = None, None
    for m in range(layout.n_cascades):
        ix = np.nonzero(occupied[m])
        if not len(ix[0]):
            continue
        idx = np.stack(ix, 1)
        a = layout.lo(m) + idx.min(0) * layout.cell(m)
        b = layout.lo(m) + (idx.max(0) + 1) * layout.cell(m)
        lo_occ = a if lo_occ is None else np.minimum(lo_occ, a)
        hi_occ = b if hi_occ is None else np.maximum(hi_occ, b)
    if lo_occ is None:  # nothing occupied: the whole finest cascade
        lo_occ, hi_occ = layout.lo(0), layout.lo(0) + layout.cell(0) * R
    for k in range(layout.n_cascades):
        h = layout.cell(k)
        origin = layout.lo(k)
        i0 = np.floor((lo_occ - origin) / h + 1e-9)
        i1 = np.ceil((hi_occ - origin) / h - 1e-9)
        shape = np.maximum(i1 - i0, 1).astype(int)
        if shape.max() <= max_side or k == layout.n_cascades - 1:
            return LatticeBox(k, origin + i0 * h, h, (int(shape[0]), int(shape[1]), int(shape[2])))
    raise AssertionError("unreachable")


def merge_cascades(
    cascades: np.ndarray, layout: CascadeLayout, occupied: np.ndarray, max_side: int = 256
) -> tuple[np.ndarray, LatticeBox]:
    """One ``[nx, ny, nz]`` float32 lattice of the cascades (module docstring).

    Args:
        cascades: ``[C, R, R, R]`` values indexed ``[x, y, z]`` (negative = unknown, read as 0).
        occupied: ``[C, R, R, R]`` bool, the cells whose box the lattice covers.
        max_side: the lattice's longest side at most (coarser cascade cells otherwise).
    """
    box = _choose_box(occupied, layout, max_side)
    out = np.zeros(box.shape, np.float32)
    R = layout.resolution
    for m in reversed(range(layout.n_cascades)):  # coarsest first: finer ones overwrite
        vals = np.maximum(np.asarray(cascades[m], np.float32), 0.0)
        h_m, lo_m = layout.cell(m), layout.lo(m)
        f = box.cell / h_m
        fi = int(round(f))
        if fi > 1 and abs(f - fi) < 1e-6 and R % fi == 0:
            # finer than the lattice: pool into lattice-sized blocks aligned with it
            off = np.round((box.lo - lo_m) / h_m).astype(int) % fi
            if np.all(off == 0):
                vals, h_m = _pool(vals, fi), box.cell
        first, last = _cell_range(lo_m, lo_m + h_m * vals.shape[0], box)
        if np.any(last <= first):
            continue
        axes = []
        for a in range(3):
            centres = box.lo[a] + (np.arange(first[a], last[a]) + 0.5) * box.cell
            axes.append(np.clip(np.floor((centres - lo_m[a]) / h_m).astype(int), 0, len(vals) - 1))
        out[first[0] : last[0], first[1] : last[1], first[2] : last[2]] = vals[np.ix_(*axes)]
    return out, box


def _any_over(a: np.ndarray, axis: int, j0: np.ndarray, j1: np.ndarray) -> np.ndarray:
    """Along ``axis``: for each output ``x``, whether any of ``a[j0[x]:j1[x]]`` is set."""
    cs = np.cumsum(np.moveaxis(a, axis, 0), axis=0, dtype=np.int64)
    cs = np.concatenate([np.zeros((1,) + cs.shape[1:], np.int64), cs], 0)
    return np.moveaxis((cs[j1] - cs[j0]) > 0, 0, axis)


def cascade_mask(selection: np.ndarray, layout: CascadeLayout, box: LatticeBox) -> np.ndarray:
    """``[C, R, R, R]`` bool: the raw cells a selected lattice cell overlaps.

    ``selection`` is ``[nx, ny, nz]`` bool on ``box``.
    """
    R, C = layout.resolution, layout.n_cascades
    sel = np.asarray(selection, bool)
    keep = np.zeros((C, R, R, R), bool)
    if not sel.any():
        return keep
    edges = [box.lo[a] + np.arange(box.shape[a] + 1) * box.cell for a in range(3)]
    for m in range(C):
        h_m, lo_m = layout.cell(m), layout.lo(m)
        k = sel
        for a in range(3):
            r = lo_m[a] + np.arange(R + 1) * h_m  # raw cell edges on this axis
            tol = 1e-9 * max(h_m, box.cell)
            # lattice cells j with [E_j, E_j+1) overlapping raw cell [r_x, r_x+1)
            j0 = np.searchsorted(edges[a][1:], r[:-1] + tol, side="right")
            j1 = np.searchsorted(edges[a][:-1], r[1:] - tol, side="left")
            k = _any_over(k, a, j0, np.maximum(j1, j0))
        keep[m] = k
    return keep

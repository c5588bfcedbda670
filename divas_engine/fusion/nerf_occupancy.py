"""NeRF occupancy: the active cells of a :class:`~divas_engine.scene.DensityGrid`
(paper App. A "Occupancy from ray-marched density", alg:nerf-fusion "density-based
empty-voxel skip").

Active cells are those with ``σ ≥ ρ_thresh``; the fusion kernel runs one thread per
active cell, so its accumulators (and P) are ∝ active cells. Cells keep the grid's own
lattice: ``grid_resolution`` of the preset (128 LLFF / 256 Mip-NeRF 360) is the
resolution the density grid should be exported at; a grid at another resolution is
used as is and the mismatch is reported (``resolution_matches``), never resampled.
Δx (the cascade voxel edge of eq:dist_tol / eq:depth_tol) is the largest cell edge.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from divas_kernels import (
    Device,
    DeviceArray,
    NerfGridGeom,
    make_nerf_grid_geom,
    resolve_device,
    to_device,
)

from ..scene import DensityGrid
from .config import NerfFusionConfig

__all__ = ["NerfOccupancy", "NerfBuildReport", "build_nerf_occupancy"]


@dataclass
class NerfBuildReport:
    shape_xyz: tuple[int, int, int]
    n_cells: int
    n_active: int
    active_fraction: float
    n_thin_eligible: int
    voxel_edge: float
    resolution_matches: bool
    build_time_s: float
    resident_bytes: int

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(eq=False)
class NerfOccupancy:
    """Active cells of a density grid on ``device``.

    Attributes:
        index: ``[A] int32`` ascending linear cell index ``(iz·ny + iy)·nx + ix``.
        density: ``[A] float32`` σ of each active cell.
        shape_xyz: (nx, ny, nz); aabb: ``[2,3]``; cell: ``[3]`` cell edges; dx: Δx.
    """

    index: DeviceArray
    density: DeviceArray
    shape_xyz: tuple[int, int, int]
    aabb: np.ndarray
    cell: np.ndarray
    dx: float
    config: NerfFusionConfig
    device: Device
    report: NerfBuildReport

    def __len__(self) -> int:
        return self.index.shape[0]

    def device_geom(self) -> NerfGridGeom:
        return make_nerf_grid_geom(self.aabb[0], self.cell, self.shape_xyz, self.dx)

    def centers(self) -> np.ndarray:
        """``[A,3]`` float64 world centres of the active cells."""
        lin = self.index.numpy().astype(np.int64)
        nx, ny, _ = self.shape_xyz
        ijk = np.stack([lin % nx, (lin // nx) % ny, lin // (nx * ny)], -1)
        return self.aabb[0] + (ijk + 0.5) * self.cell

    def lookup(self, linear: np.ndarray) -> np.ndarray:
        """``[M] int32`` active index of linear cell indices (−1 when inactive)."""
        idx = self.index.numpy()
        lin = np.asarray(linear, dtype=np.int64)
        pos = np.searchsorted(idx, lin)
        hit = (
            (pos < len(idx)) & (idx[np.minimum(pos, len(idx) - 1)] == lin)
            if len(idx)
            else np.zeros(lin.shape, bool)
        )
        return np.where(hit, pos, -1).astype(np.int32)

    def to_dense(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Scatter per-active values ``[A]`` into a ``[D,H,W]`` grid (e.g. P for export)."""
        nx, ny, nz = self.shape_xyz
        out = np.full(nz * ny * nx, fill, dtype=np.asarray(values).dtype)
        out[self.index.numpy()] = values
        return out.reshape(nz, ny, nx)


def build_nerf_occupancy(grid: DensityGrid, config: NerfFusionConfig, device=None) -> NerfOccupancy:
    """Active cells ``σ ≥ ρ_thresh`` of ``grid`` (linear order) on ``device``."""
    device = resolve_device(device)
    t0 = time.perf_counter()
    dens = np.asarray(grid.density, dtype=np.float32)
    if dens.ndim != 3:
        raise ValueError(f"build_nerf_occupancy: density must be [D,H,W], got {dens.shape}")
    flat = dens.reshape(-1)
    with np.errstate(invalid="ignore"):
        lin = np.flatnonzero(flat >= config.rho_thresh)
    if flat.size >= 2**31:
        raise ValueError("build_nerf_occupancy: grids above 2^31 cells are not supported")
    cell = np.asarray(grid.voxel_size, dtype=np.float64)
    occ = NerfOccupancy(
        to_device(lin.astype(np.int32), device),
        to_device(flat[lin], device, dtype=np.float32),
        grid.shape_xyz,
        np.asarray(grid.aabb, dtype=np.float64),
        cell,
        float(cell.max()),
        config,
        device,
        None,
    )  # type: ignore[arg-type]
    res = config.grid_resolution
    occ.report = NerfBuildReport(
        shape_xyz=tuple(grid.shape_xyz),
        n_cells=int(flat.size),
        n_active=len(lin),
        active_fraction=len(lin) / max(flat.size, 1),
        n_thin_eligible=int((flat[lin] >= config.rho_thin).sum()),
        voxel_edge=float(cell.max()),
        resolution_matches=tuple(grid.shape_xyz) == (res, res, res),
        build_time_s=time.perf_counter() - t0,
        resident_bytes=occ.index.capacity + occ.density.capacity,
    )
    return occ

"""Occupancy grids and 3D fusion (paper Sec. 3.5, App. A, App. B).

* 2DGS: :func:`build_occupancy` → :class:`OccupancyGrid` (Morton-sorted active voxels,
  hash lookup) → :class:`GsFusion` (incremental, exactly undoable; P, V_seg, view bitmask).
* NeRF: :func:`build_nerf_occupancy` → :class:`NerfOccupancy` → :class:`NerfFusion`.
* Inputs per view: :class:`FusionView`. Constants: :class:`GridConfig`,
  :class:`GsFusionConfig`, :class:`NerfFusionConfig` / :func:`nerf_preset`.
"""

from .config import NERF_PRESETS, GridConfig, GsFusionConfig, NerfFusionConfig, nerf_preset
from .gs_fusion import GsFusion, fuse_views_gs
from .nerf_fusion import NerfFusion, fuse_views_nerf
from .nerf_occupancy import NerfOccupancy, build_nerf_occupancy
from .occupancy import (
    GridGeometry,
    OccupancyGrid,
    build_occupancy,
    grid_geometry,
    surfel_voxel_codes,
)
from .state import FusionCapacityError, FusionResult
from .views import FusionView

__all__ = [
    "GridConfig",
    "GsFusionConfig",
    "NerfFusionConfig",
    "NERF_PRESETS",
    "nerf_preset",
    "GridGeometry",
    "OccupancyGrid",
    "build_occupancy",
    "grid_geometry",
    "surfel_voxel_codes",
    "NerfOccupancy",
    "build_nerf_occupancy",
    "FusionView",
    "GsFusion",
    "NerfFusion",
    "fuse_views_gs",
    "fuse_views_nerf",
    "FusionResult",
    "FusionCapacityError",
]

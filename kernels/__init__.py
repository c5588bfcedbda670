"""Warp kernels of DivAS. Every kernel runs on ``cpu`` and ``cuda``; the device is a
parameter of the Python wrapper, never hard-coded. The engine calls only the
wrappers listed in ``__all__`` (never ``wp.launch`` directly).
"""

from ._launch import cpu_threads, resolve_device
from .coverage import compact, make_coverage_view, run_coverage, run_pass1, run_pass2, run_select
from .fusion_accum import apply_records, compact_contributions, readout
from .fusion_common import depth_gradient_factor
from .fusion_gs import gs_fuse_view
from .fusion_nerf import nerf_fuse_view
from .integral_image import integral_images
from .occupancy import build_active, hash_build, hash_query, make_grid_geom, surfel_codes
from .rasterize import (
    RasterOutput,
    RasterSettings,
    SurfelBuffers,
    rasterize_surfels,
    upload_surfels,
)
from .raymarch import GridBuffers, MarchSettings, raymarch_grid, upload_grid

__all__: list[str] = [
    "cpu_threads",
    "resolve_device",
    "RasterOutput",
    "RasterSettings",
    "SurfelBuffers",
    "rasterize_surfels",
    "upload_surfels",
    "GridBuffers",
    "MarchSettings",
    "raymarch_grid",
    "upload_grid",
    # occupancy and fusion (divas_engine.fusion)
    "surfel_codes",
    "build_active",
    "hash_build",
    "hash_query",
    "make_grid_geom",
    "integral_images",
    "depth_gradient_factor",
    "compact_contributions",
    "apply_records",
    "readout",
    "gs_fuse_view",
    "nerf_fuse_view",
    # voxel-to-surfel mapping (divas_engine.mapping)
    "make_coverage_view",
    "run_pass1",
    "run_pass2",
    "compact",
    "run_coverage",
    "run_select",
]

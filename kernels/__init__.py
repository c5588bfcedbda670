"""Warp kernels of DivAS. Every kernel runs on ``cpu`` and ``cuda``; the device is a
parameter of the Python wrapper, never hard-coded. The engine calls only the
wrappers listed in ``__all__`` (never ``wp.launch`` directly, never a submodule):
device arrays are allocated and uploaded here too (:mod:`.device_arrays`).
"""

from . import render_defaults
from ._launch import THREADS_ENV, cpu_threads, resolve_device, set_thread_source, usable_cores
from .contrib import ContribOutput, accumulate_contributions
from .coverage import (
    CoverageView,
    compact,
    make_coverage_view,
    run_coverage,
    run_pass1,
    run_pass2,
    run_select,
    upload_coverage_views,
)
from .device_arrays import (
    Device,
    DeviceArray,
    cuda_device_count,
    device_append,
    device_synchronize,
    device_zeros,
    is_device_array,
    to_device,
)
from .fusion_accum import (
    ContributionBuffers,
    Records,
    alloc_accumulators,
    apply_records,
    compact_contributions,
    readout,
)
from .fusion_common import QSCALE, ViewData, depth_gradient_factor, upload_view_data
from .fusion_gs import GsParams, gs_fuse_view
from .fusion_nerf import NerfGridGeom, NerfParams, make_nerf_grid_geom, nerf_fuse_view
from .integral_image import integral_images
from .ngp_field import NgpNetBuffers, eval_ngp_points, upload_ngp_network
from .occupancy import (
    GridGeom,
    build_active,
    hash_build,
    hash_query,
    make_grid_geom,
    surfel_codes,
)
from .rasterize import (
    RasterOutput,
    RasterSettings,
    SurfelBuffers,
    ViewBinning,
    binning_key,
    rasterize_surfels,
    surfel_rows,
    upload_surfels,
)
from .raymarch import GridBuffers, MarchSettings, raymarch_grid, upload_grid
from .raymarch_ngp import NgpMarchSettings, NgpOccupancy, raymarch_ngp, upload_ngp_occupancy
from .scratch import ScratchPool, recycling
from .splat import pixel_window

__all__: list[str] = [
    "cpu_threads",
    "set_thread_source",
    "usable_cores",
    "THREADS_ENV",
    "resolve_device",
    "render_defaults",
    # device arrays (allocation and upload stay behind the boundary)
    "Device",
    "DeviceArray",
    "to_device",
    "device_zeros",
    "device_append",
    "device_synchronize",
    "cuda_device_count",
    "is_device_array",
    # renderers (divas_engine.render)
    "RasterOutput",
    "RasterSettings",
    "SurfelBuffers",
    "ViewBinning",
    "pixel_window",
    "binning_key",
    "rasterize_surfels",
    "ScratchPool",
    "recycling",
    "surfel_rows",
    "upload_surfels",
    "GridBuffers",
    "MarchSettings",
    "raymarch_grid",
    "upload_grid",
    # instant-ngp radiance networks
    "NgpNetBuffers",
    "upload_ngp_network",
    "eval_ngp_points",
    "NgpMarchSettings",
    "NgpOccupancy",
    "upload_ngp_occupancy",
    "raymarch_ngp",
    # per-surfel blending contributions (evaluation baselines)
    "ContribOutput",
    "accumulate_contributions",
    # occupancy and fusion (divas_engine.fusion)
    "GridGeom",
    "surfel_codes",
    "build_active",
    "hash_build",
    "hash_query",
    "make_grid_geom",
    "integral_images",
    "depth_gradient_factor",
    "QSCALE",
    "ViewData",
    "upload_view_data",
    "Records",
    "ContributionBuffers",
    "alloc_accumulators",
    "compact_contributions",
    "apply_records",
    "readout",
    "GsParams",
    "gs_fuse_view",
    "NerfGridGeom",
    "NerfParams",
    "make_nerf_grid_geom",
    "nerf_fuse_view",
    # voxel-to-surfel mapping (divas_engine.mapping)
    "CoverageView",
    "make_coverage_view",
    "upload_coverage_views",
    "run_pass1",
    "run_pass2",
    "compact",
    "run_coverage",
    "run_select",
]

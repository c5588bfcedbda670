"""The weight-free default segmenter: a 3D cut over the scene's primitives.

* :mod:`.primitives` — the scene's primitives as graph nodes (position, Lab colour,
  normal and its confidence, opacity) and its supporting planes;
* :mod:`.voxel_graph` — one prompt's local active-voxel graph with affinities;
* :mod:`.cut` — seeded random walk + sweep cut by conductance → three nested regions
  and their scores;
* :mod:`.segmenter` — :class:`Graph3DSegmenter`: seeds from the clicks' depth, the cut,
  the regions rendered into the view as SAM-like masks.
"""

from .config import Graph3DConfig
from .cut import CutResult, Granularity, sweep_cut, walk_potential
from .primitives import ScenePrimitives
from .segmenter import Graph3DSegmenter, RegionCut, Seeds
from .voxel_graph import VoxelGraph, build_voxel_graph

__all__ = [
    "Graph3DConfig",
    "Graph3DSegmenter",
    "RegionCut",
    "Seeds",
    "ScenePrimitives",
    "VoxelGraph",
    "build_voxel_graph",
    "CutResult",
    "Granularity",
    "sweep_cut",
    "walk_potential",
]

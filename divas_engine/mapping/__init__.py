"""2DGS voxel-to-surfel mapping (paper Sec. 3.6, App. B, alg:vox2surfel): the monotone
chain f¹ ⪰ f² ⪰ f — Morton admission, needle cull, footprint coverage.

* :class:`SurfelMapper` — per-scene state (uploaded once); ``.map(fused, views, slots)``
  after each fusion update → :class:`MappingResult`.
* :func:`map_to_surfels` — one-shot form. Constants: :class:`MappingConfig`.
* :class:`~.completion.VolumetricCompletion` — beyond the paper: completion of the
  selection on 3DGS-derived scenes, constants :class:`CompletionConfig`.
"""

from .config import CompletionConfig, MappingConfig
from .passes import MappingResult, SurfelMapper, map_to_surfels, needle_threshold, surfel_aspects

__all__ = [
    "CompletionConfig",
    "MappingConfig",
    "MappingResult",
    "SurfelMapper",
    "map_to_surfels",
    "needle_threshold",
    "surfel_aspects",
]

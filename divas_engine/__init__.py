"""DivAS engine: pure-Python (no ``bpy``) interactive 3D segmentation of splat and NeRF scenes.

Public entry points are re-exported here; see ``README.md`` for the layer rules.
"""

from .camera import Camera
from .errors import DivasInputError
from .scene import DensityGrid, Scene, SourceInfo, SurfelScene

__all__ = [
    "Camera",
    "DivasInputError",
    "DensityGrid",
    "Scene",
    "SourceInfo",
    "SurfelScene",
    "load_scene",
]
__version__ = "0.1.0"


def load_scene(path, **kwargs):
    """Load any supported scene file (see :func:`divas_engine.io.load.load_scene`)."""
    from .io.load import load_scene as _load

    return _load(path, **kwargs)

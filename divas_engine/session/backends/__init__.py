"""Session backends: one per scene representation (surfels, density grids).

:func:`backend_class_for` picks the backend of a scene from the registry; importing
this package registers the built-in ones. See :mod:`.base` for the interface.
"""

from .base import SessionBackend
from .density_grid import DensityGridBackend
from .registry import backend_class_for, register_backend, registered_backends
from .surfels import SurfelBackend

__all__ = [
    "SessionBackend",
    "SurfelBackend",
    "DensityGridBackend",
    "backend_class_for",
    "register_backend",
    "registered_backends",
]

"""The scene → session backend registry (one backend per scene representation)."""

from __future__ import annotations

from typing import TypeVar

from ...scene import Scene
from .base import SessionBackend

__all__ = ["register_backend", "backend_class_for", "registered_backends"]

#: scene type → the backend of its scenes
_BACKENDS: dict[type, type[SessionBackend]] = {}

B = TypeVar("B", bound=type[SessionBackend])


def register_backend(cls: B) -> B:
    """Class decorator: make ``cls`` the backend of scenes of ``cls.scene_type``."""
    if not (isinstance(cls, type) and issubclass(cls, SessionBackend)):
        raise TypeError(f"register_backend: {cls!r} is not a SessionBackend subclass")
    if cls.scene_type in _BACKENDS:
        raise ValueError(f"a session backend for {cls.scene_type.__name__} is already registered")
    _BACKENDS[cls.scene_type] = cls
    return cls


def registered_backends() -> dict[type, type[SessionBackend]]:
    """A copy of the registry: scene type → backend class."""
    return dict(_BACKENDS)


def backend_class_for(scene: Scene) -> type[SessionBackend]:
    """The backend registered for ``scene``'s type, or else for its nearest base class."""
    for t in type(scene).__mro__:
        if t in _BACKENDS:
            return _BACKENDS[t]
    raise TypeError(f"unsupported scene type {type(scene).__name__}")

"""What a session does differently per scene representation.

:class:`~divas_engine.session.Session` runs the same loop on every scene (paper Sec. 3:
click → centroid view → mask → fuse → selection); a :class:`SessionBackend` supplies the
steps that depend on what the scene is made of. A backend is built once per session,
from the scene, and owns the representation's occupancy grid and fusion state.

A new representation: subclass :class:`SessionBackend`, set ``scene_type`` and ``kind``,
implement the abstract methods and decorate the class with
:func:`~divas_engine.session.backends.register_backend`; the loop does not change.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ...camera import Camera
from ...kinds import SceneKind
from ...render.buffers import RenderBuffers
from ...scene import Scene
from ...segment.depth_weighting import DepthBand
from ...views.centroid_common import CentroidView

if TYPE_CHECKING:
    from ...fusion import FusionResult
    from ..config import SessionConfig
    from ..records import SessionView

__all__ = ["SessionBackend"]


class SessionBackend(ABC):
    """The representation-specific half of a session.

    Class attributes:
        scene_type: the scene class this backend serves (the registry matches scenes
            with ``isinstance``).
        kind: the session's kind, recorded in reports and saved sessions and used for
            anchor planning (Sec. 3.2).

    Attributes (set by ``__init__``):
        grid: the occupancy grid of the active voxels (``len(grid)`` active voxels,
            ``grid.report`` build statistics).
        fusion: the incremental, exactly undoable fusion state over ``grid``
            (:class:`~divas_engine.fusion.state.IncrementalFusion`).
    """

    scene_type: ClassVar[type]
    kind: ClassVar[SceneKind]

    grid: Any
    fusion: Any
    #: surfel scenes: the occupancy :class:`~divas_engine.fusion.GridConfig`; else None
    grid_config: Any = None
    #: density grids: the :class:`~divas_engine.fusion.NerfFusionConfig`; else None
    nerf_config: Any = None
    #: surfel scenes: the latest voxel-to-surfel mapping result; else None
    last_mapping: Any = None
    #: 3DGS scenes with the completion on: its latest result; else None
    last_completion: Any = None
    #: the depth weighting reads the prompts (2DGS: the band of the positive prompts'
    #: depths), so a positive click can change a view's weighted mask where its
    #: segmenter's mask already holds the spot (:func:`..corrections.disagrees`)
    weight_reads_prompts: ClassVar[bool] = False
    _warm: threading.Thread | None = None

    @property
    def ready(self) -> bool:
        """Reading the fusion state would not wait for a warm-up (default: always)."""
        return True

    def warm_up(self, then: Callable[[], None] | None = None) -> None:
        """Start work that the first anchor does not need in a background thread: the
        backend's own (e.g. the fusion state), then ``then`` (the segmenter's warm-up) in
        the same thread; the default has nothing of its own and runs ``then`` alone.
        Called once by :meth:`Session.open` after the first anchor is rendered."""
        if then is not None:
            self._warm = threading.Thread(target=then, name="divas-warm-up", daemon=True)
            self._warm.start()

    def wait_warm_up(self, timeout: float | None = None) -> bool:
        """Wait for the whole background warm-up (the segmenter's part too); whether it
        is done."""
        t = self._warm
        if t is not None:
            t.join(timeout)
        return t is None or not t.is_alive()

    def __init__(
        self, scene: Scene, config: SessionConfig, *, forward_facing: bool, device, renderer
    ) -> None:
        self.scene = scene
        self.config = config
        self.forward_facing = bool(forward_facing)
        self.device = device
        self.renderer = renderer

    # ---------------------------------------------------------------- scene facts
    @staticmethod
    @abstractmethod
    def fingerprint_array(scene: Scene) -> np.ndarray:
        """The array that identifies the scene in a saved session (hashed)."""

    @property
    @abstractmethod
    def selection_shape(self) -> tuple[int, ...]:
        """Shape of a selection, of the label set and of ground-truth values."""

    # ---------------------------------------------------------------- clicks and views
    @abstractmethod
    def click_depth(self, buffers: RenderBuffers) -> np.ndarray:
        """The depth map a click on an anchor render is back-projected with."""

    def click_depth_at(
        self, camera: Camera, xy: tuple[float, float], buffers: RenderBuffers
    ) -> float | None:
        """The depth of the surface a click at ``xy`` of ``buffers`` lands on when it is
        not :meth:`click_depth`'s there (None: the map's; a backend that sees the
        pixel's layers overrides it)."""
        return None

    @abstractmethod
    def centroid_view(
        self,
        camera: Camera,
        xy: tuple[float, float],
        buffers: RenderBuffers,
        name: str,
        on_camera: Callable[[Camera], None] | None = None,
    ) -> CentroidView:
        """The centroid view a positive click spawns (Sec. 3.3). ``on_camera`` is called
        with the view's camera before the view is rendered (here or by the session):
        the session starts work that needs only the camera meanwhile."""

    @abstractmethod
    def click_patch(self, point: np.ndarray, radius: float, sigmas: float) -> np.ndarray:
        """The surface patch of a click at ``point`` (:mod:`..corrections`): sorted flat
        indices (into a selection) of the primitives or voxels the point lies in, each
        grown by ``radius`` (world units), within ``sigmas`` standard deviations
        (:func:`~..corrections.surfel_patch`, :func:`~..corrections.grid_patch`)."""

    def pixel_weights(
        self, camera: Camera, xy: tuple[float, float]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """What draws pixel ``xy`` of ``camera`` (rendered at its size): ``(rows, w,
        centres)``, the flat indices of the primitives with a blending weight ``w = α·T``
        there and their ``[K,3]`` centres; None where the backend has no such weights
        (the density grid: a click's patch stays its voxels)."""
        return None

    # ---------------------------------------------------------------- masks and fusion
    @abstractmethod
    def depth_weight(
        self, mask: np.ndarray, buffers: RenderBuffers, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, DepthBand | None]:
        """The depth-weighted mask M̃ of a selected SAM mask (Sec. 3.4) and its band."""

    @property
    @abstractmethod
    def asynchronous(self) -> bool:
        """Accepted views are segmented by the background worker and fused in groups
        (Sec. 3.4 "Execution scheduling"), rather than one by one at accept."""

    @abstractmethod
    def selection(self, fused: FusionResult, live: Sequence[SessionView]) -> np.ndarray:
        """The selection (bool, :attr:`selection_shape`) of the fused live views."""

    # ---------------------------------------------------------------- export
    @abstractmethod
    def object_suffix(self) -> str:
        """File suffix of one exported object (the input's own format)."""

    @abstractmethod
    def write_label_set(self, labels: np.ndarray, out_dir: Path) -> Path:
        """Write the integer label set into ``out_dir``; returns the file."""

    def write_labelled(self, labels: np.ndarray, path: str | PathLike) -> Path:
        """The scene with its labels as a column, where the representation has one."""
        from ...errors import DivasInputError

        raise DivasInputError(path, f"a labelled scene file is not available for {self.kind}")

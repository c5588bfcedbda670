"""Session backend of surfel scenes (2DGS, and 3DGS loaded flattened to surfels).

Occupancy from the surfels (App. A), the 2DGS centroid-view planner (Sec. 3.3), the
depth band-pass (eq:gs-bandpass), synchronous fusion with the view bitmask (eq:vmask)
and the voxel-to-surfel mapping (Sec. 3.6); exports are surfel files.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...camera import Camera
from ...geometry import quat_to_rotmat
from ...kinds import SceneKind
from ...render.buffers import RenderBuffers
from ...scene import Scene, SurfelScene
from ...segment.depth_weighting import DepthBand, apply_gs_bandpass
from ...views.centroid_common import CentroidView
from .base import SessionBackend
from .registry import register_backend

if TYPE_CHECKING:
    from ...fusion import FusionResult
    from ..config import SessionConfig
    from ..records import SessionView

__all__ = ["SurfelBackend"]


def _ray_splat_depths(
    camera: Camera, xy, centres: np.ndarray, normals: np.ndarray, z_centre: np.ndarray
) -> np.ndarray:
    """Planar depths where the ray through pixel ``xy`` meets each splat's plane (its
    centre and normal), as the rasterizer evaluates them; a splat the ray runs along
    keeps its centre's depth."""
    o = np.asarray(camera.center, np.float64)
    q = camera.unproject(np.array([[xy[0], xy[1]]], np.float64), np.array([1.0]))[0] - o
    n = np.asarray(normals, np.float64)
    den = n @ q
    num = np.einsum("ij,ij->i", n, np.asarray(centres, np.float64) - o)
    edge = np.abs(den) < 1e-6 * np.linalg.norm(q)
    return np.where(edge, z_centre, num / np.where(edge, 1.0, den))


@register_backend
class SurfelBackend(SessionBackend):
    """Surfel scenes: the 2DGS path of the paper (the session kind is ``GS2D`` for both
    Gaussian kinds).

    Attributes:
        grid_config: the occupancy config in use (``SessionConfig.grid``, else
            ``g_max`` 512 forward-facing / 1024 otherwise, NOTES "Occupancy").
        last_mapping: the latest voxel-to-surfel :class:`~divas_engine.mapping.MappingResult`.
        last_completion: on 3DGS scenes with ``config.mapping.completion.enabled``, the
            latest :class:`~divas_engine.mapping.completion.CompletionResult` (beyond the
            paper); else None.

    The occupancy geometry is computed at construction (a degenerate scene fails at
    open); the active voxels, the fusion state, the voxel-to-surfel mapper
    and the click neighbourhood's centres are built by :meth:`warm_up` in a background
    thread while the user looks at the first anchor, or on first use (``grid`` and
    ``fusion`` wait for it). The same functions run on the same inputs: the state is
    identical to building it at open.
    """

    scene_type = SurfelScene
    kind = SceneKind.GS2D
    weight_reads_prompts = True

    def __init__(
        self, scene: Scene, config: SessionConfig, *, forward_facing: bool, device, renderer
    ) -> None:
        from ...fusion import GridConfig
        from ...fusion.occupancy import grid_geometry

        super().__init__(
            scene, config, forward_facing=forward_facing, device=device, renderer=renderer
        )
        self.grid_config = config.grid or (
            GridConfig.forward_facing() if self.forward_facing else GridConfig()
        )
        self._geometry = grid_geometry(scene.means, scene.scales, self.grid_config)
        self._build_config = config  # the state is built with the config given here
        self.last_mapping = None
        self.last_completion = None
        self._planner = None
        self._reach: np.ndarray | None = None
        self._completion = None
        self._evidence: dict[int, tuple] = {}
        self._state: tuple | None = None  # (grid, fusion, mapper)
        self._state_error: BaseException | None = None
        self._state_lock = threading.Lock()
        self._warm: threading.Thread | None = None
        self._warm_done = threading.Event()

    # --- deferred state ----------------------------------------------------------
    def _build_state(self) -> None:
        from ...fusion import GsFusion, build_occupancy
        from ...mapping import SurfelMapper

        with self._state_lock:
            if self._state is not None or self._state_error is not None:
                return
            try:
                grid = build_occupancy(self.scene, self.grid_config, self.device, self._geometry)
                cfg = self._build_config
                fusion = GsFusion(grid, cfg.gs_fusion, self.device)
                # the renderer's surfel buffers: no second copy of the centres and tangents
                bufs = self.renderer.surfel_buffers
                mapper = SurfelMapper(self.scene, grid, cfg.mapping, self.device, surfels=bufs)
                self._state = (grid, fusion, mapper)
            except BaseException as e:  # noqa: BLE001 - re-raised on first use
                self._state_error = e
        if self._state is not None:
            self.planner._opaque_centres()
            # the block index the renderer culls zoomed views and probes with
            self.renderer.sparse_index()

    def warm_up(self, then: Callable[[], None] | None = None) -> None:
        if self._warm is None and self._state is None:
            self._warm = threading.Thread(
                target=self._warm_up, args=(then,), name="divas-warm-up", daemon=True
            )
            self._warm.start()

    def _warm_up(self, then: Callable[[], None] | None) -> None:
        """The background thread: the fusion state (readers wait for this part only),
        then the segmenter's warm-up."""
        try:
            self._build_state()
        finally:
            self._warm_done.set()
        if then is not None:
            then()

    @property
    def ready(self) -> bool:
        return self._state is not None or self._state_error is not None

    def _ready(self) -> tuple:
        if self._warm is not None:
            self._warm_done.wait()
        if self._state is None:
            self._build_state()
        if self._state_error is not None:
            raise self._state_error
        return self._state

    @property
    def grid(self):
        return self._ready()[0]

    @property
    def fusion(self):
        return self._ready()[1]

    @property
    def planner(self):
        if self._planner is None:
            from ...views import GsCentroidPlanner

            self._planner = GsCentroidPlanner(self.scene, self.renderer, self.config.view)
        return self._planner

    @staticmethod
    def fingerprint_array(scene: Scene) -> np.ndarray:
        return scene.means

    @property
    def selection_shape(self) -> tuple[int, ...]:
        return (len(self.scene),)

    def click_depth(self, buffers: RenderBuffers) -> np.ndarray:
        return buffers.D_med

    def centroid_view(
        self,
        camera: Camera,
        xy: tuple[float, float],
        buffers: RenderBuffers,
        name: str,
        on_camera: Callable[[Camera], None] | None = None,
    ) -> CentroidView:
        depth = self.click_depth_at(camera, xy, buffers)
        return self.planner.centroid_view(
            camera, xy, buffers, name=name, on_camera=on_camera, depth=depth
        )

    def click_depth_at(
        self, camera: Camera, xy: tuple[float, float], buffers: RenderBuffers
    ) -> float | None:
        """The nearer surface a click lands on, when one draws enough of its pixel
        (:class:`~divas_engine.views.config.ViewConfig` ``front_share``, ``front_gap``):
        over the splats drawing the pixel in blend order (centre depth), ``1 − T`` first
        reaches the share at a splat of ray–splat depth ``z`` — the renderer's ``D_med``
        rule at a third instead of a half — and the splats within ``front_gap · z`` of
        that depth draw the share themselves (a surface, not a haze of faint splats
        spread in depth), more than ``front_gap`` in front of ``D_med``. None when the
        click's surface is ``D_med``'s. Beyond the paper."""
        cfg = self.config.view
        x, y = int(np.floor(xy[0])), int(np.floor(xy[1]))
        h, w = buffers.D_med.shape
        if not (0 <= x < w and 0 <= y < h) or cfg.front_share >= 0.5:
            return None
        d_med = float(buffers.D_med[y, x])
        pw = self.pixel_weights(camera, (x + 0.5, y + 0.5))
        if d_med <= 0.0 or pw is None or len(pw[0]) == 0:
            return None
        rows, wts, centres = pw
        _, z_centre = camera.project(centres)
        order = np.argsort(z_centre, kind="stable")  # the blend order
        k = int(np.searchsorted(np.cumsum(wts[order]), cfg.front_share))
        if k >= len(order):
            return None
        normals = quat_to_rotmat(np.asarray(self.scene.quats[rows]))[:, :, 2]
        z = _ray_splat_depths(camera, (x + 0.5, y + 0.5), centres, normals, z_centre)
        z_front = float(z[order[k]])
        if not (camera.near < z_front < d_med * (1.0 - cfg.front_gap)):
            return None
        band = np.abs(z - z_front) <= cfg.front_gap * z_front
        return z_front if float(wts[band].sum()) >= cfg.front_share else None

    def click_patch(self, point: np.ndarray, radius: float, sigmas: float) -> np.ndarray:
        from ..corrections import surfel_patch

        sc = self.scene
        if self._reach is None:  # per primitive: its largest standard deviation
            s = np.max(sc.scales, axis=1)
            self._reach = (s if sc.scale_n is None else np.maximum(s, sc.scale_n)).astype(
                np.float32
            )
        return surfel_patch(sc, point, radius, sigmas, self._reach)

    def pixel_weights(
        self, camera: Camera, xy: tuple[float, float]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        x, y = int(np.floor(xy[0])), int(np.floor(xy[1]))
        if not (0 <= x < camera.width and 0 <= y < camera.height):
            return None
        pixel = np.zeros((camera.height, camera.width), bool)
        pixel[y, x] = True
        out = self.renderer.contributions(camera, pixel, window=(x, y, x + 1, y + 1))
        w = out.a1.numpy()
        rows = np.flatnonzero(w > 0)
        return rows, w[rows].astype(np.float64), np.asarray(self.scene.means[rows], np.float64)

    def depth_weight(
        self, mask: np.ndarray, buffers: RenderBuffers, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, DepthBand | None]:
        return apply_gs_bandpass(mask, buffers.D_ref, points, labels, config=self.config.bandpass)

    @property
    def asynchronous(self) -> bool:
        return False

    def selection(self, fused: FusionResult, live: Sequence[SessionView]) -> np.ndarray:
        mapper = self._ready()[2]
        res = mapper.map(
            fused,
            [v.fusion_view for v in live],
            [int(v.fusion_id) for v in live],
            self.config.mapping,
        )
        self.last_mapping = res
        sel = np.asarray(res.selected, dtype=bool)
        comp = self.config.mapping.completion
        if self.scene.kind != SceneKind.GS3D or not comp.enabled:
            self.last_completion = None
            return sel  # 2DGS: the paper's three passes exactly
        return self._complete(sel, fused, live)

    def _complete(
        self, sel: np.ndarray, fused: FusionResult, live: Sequence[SessionView]
    ) -> np.ndarray:
        """Completion of a 3DGS-derived scene (beyond the paper): the live views'
        records are added/removed incrementally, then the selection is completed."""
        from ...mapping.completion import VolumetricCompletion
        from ..widening import widened_from

        comp = self.config.mapping.completion
        if self._completion is None or self._completion.config != comp:
            self._completion = VolumetricCompletion(
                self.scene,
                self.grid,
                self._ready()[2].active_index,
                comp,
                device=self.device,
                render_config=self.config.render,
                renderer=self.renderer,
            )
        t_views = self._completion.sync(
            [(int(v.fusion_id), self._evidence_view(v)) for v in live],
            {int(v.fusion_id): widened_from(v.id)[0] for v in live},  # a view's sight
        )
        res = self._completion.complete(sel, fused.segmented)
        res.seconds["views"] = t_views
        self.last_completion = res
        return res.selected

    def _evidence_view(self, v: SessionView):
        """The view the completion reads: the fused view with the segmenter's own mask
        (what the user accepted) in place of the depth-weighted M̃ — the band-pass
        (eq:gs-bandpass) zeroes the object's parts outside the clicked depth band, which
        the completion would read as background; cached per fused view so the
        completion's records are made once."""
        from dataclasses import replace

        fv = v.fusion_view
        hit = self._evidence.get(int(v.fusion_id))
        if hit is not None and hit[0] is fv:
            return hit[1]
        raw = v.raw_mask if v.preview is None else v.preview.selection.mask
        ev = fv if raw is None else replace(fv, mask=np.array(raw, np.float32))  # a copy
        self._evidence[int(v.fusion_id)] = (fv, ev)
        return ev

    def object_suffix(self) -> str:
        return export_suffix(self.scene)

    def write_label_set(self, labels: np.ndarray, out_dir: Path) -> Path:
        return self.write_labelled(labels, out_dir / "labelled.ply")

    def write_labelled(self, labels: np.ndarray, path: str | PathLike) -> Path:
        from ..labels_io import write_labelled_ply

        return write_labelled_ply(self.scene, labels, path)


def export_suffix(scene: SurfelScene) -> str:
    """The file suffix of an export in the input's own format ("" for an unbundled SOG
    folder)."""
    src = scene.source
    if src is None or src.format in ("ply", "compressed_ply"):
        return ".ply"
    if src.format == "sog":  # a .sog bundle, or a folder for an unbundled input
        return ".sog" if scene.extras.get("sog_bundled") else ""
    return {"splat": ".splat", "spz": ".spz"}.get(src.format, ".ply")

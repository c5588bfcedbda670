"""NeRF density-grid renderer: the ray-marcher of ``divas_kernels.raymarch`` behind the
:class:`~divas_engine.render.protocol.Renderer` base class."""

from __future__ import annotations

import numpy as np

from divas_kernels import raymarch_grid, resolve_device, upload_grid

from ..camera import Camera
from ..kinds import SceneKind
from ..scene import DensityGrid
from .buffers import RenderBuffers
from .config import RenderConfig
from .grid_shading import shaded_rgb, wants_shading
from .protocol import Renderer

__all__ = ["NerfRenderer", "MarchedViews"]


class MarchedViews(Renderer):
    """``render`` and ``render_values`` of a ray-marcher whose ``_run(camera, values)``
    returns a :class:`divas_kernels.composite.PixelOut` (the depth tuple per NOTES with
    ``D_ref = D_exp``); ``grid_shape`` is the lattice per-voxel values live on."""

    kind = SceneKind.NERF
    grid_shape: tuple[int, int, int]
    stats: dict | None = None

    def render(self, camera: Camera, scale: float = 1.0, *, attached: bool = True) -> RenderBuffers:
        """RGB and the depth tuple (``attached``: a grid has no extra channels to attach)."""
        cam = camera if scale == 1.0 else camera.scaled(scale)
        o = self._run(cam, None)
        H, W = cam.height, cam.width
        img = lambda a: a.numpy().reshape(H, W)  # noqa: E731
        d_exp = img(o.d_exp)
        return RenderBuffers(
            rgb=o.feat.numpy().reshape(H, W, 3),
            alpha=img(o.alpha),
            D_min=img(o.d_min),
            D_ref=d_exp.copy(),
            D_max=img(o.d_max),
            D_mw=img(o.d_mw),
            D_exp=d_exp,
            D_med=img(o.d_med),
            N_samp=img(o.n_samp),
            camera=cam,
            kind=self.kind,
            stats=dict(self.stats or {}),
        )

    def render_values(self, camera: Camera, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        values = np.asarray(values)
        if values.shape[:3] != self.grid_shape or values.ndim not in (3, 4):
            raise ValueError(
                f"render_values: expected per-voxel values of shape {self.grid_shape} "
                f"or {self.grid_shape}+(C,), got {values.shape}"
            )
        cam = camera if scale == 1.0 else camera.scaled(scale)
        f = self._run(cam, values).feat.numpy()
        H, W = cam.height, cam.width
        return f.reshape(H, W) if values.ndim == 3 else f.reshape(H, W, -1)


class NerfRenderer(MarchedViews):
    """Renders a :class:`DensityGrid`; the grid is uploaded to ``device`` once.

    Depth tuple per NOTES with ``D_ref = D_exp`` and ``N_samp`` anchored at ``D_max``;
    depths are planar (NOTES "Conventions": the NeRF path reports camera z too).
    Settled here (details in ``kernels/raymarch.py``): segments of ``δ = ½ min voxel
    edge`` from the AABB entry (the last one ends at the exit), sampled at their
    midpoints; every sample with α > 0 is blended, those with α ≥ 1/255 are
    "contributing" (``N_samp``, the ``D_max`` fallback); ``D_med`` is reported too.
    Without an RGB grid the colour is an instant-ngp network's baked at the voxels (a grid
    marched instead of its network: :func:`.network_views` false), else
    ``config.nerf_color``, or the grid's shape (:mod:`.grid_shading`) when
    ``config.shade_grid`` asks for it.
    """

    kind = SceneKind.NERF

    def __init__(self, grid: DensityGrid, device=None, config: RenderConfig | None = None):
        self.config = config or RenderConfig()
        self.device = resolve_device(device)
        self.grid_shape = tuple(grid.density.shape)
        rgb = grid.rgb
        if rgb is None and grid.network is not None:  # the grid marched, the network's colour
            from .ngp_renderer import bake_network_colors

            rgb = bake_network_colors(grid, self.device)
        elif wants_shading(grid, self.config.shade_grid):
            rgb = shaded_rgb(grid)
        self.shaded = rgb is not grid.rgb
        self._buf = upload_grid(grid.density, grid.aabb, rgb, self.device)

    def _run(self, cam: Camera, values: np.ndarray | None):
        return raymarch_grid(
            self._buf,
            cam.c2w,
            cam.fx,
            cam.fy,
            cam.cx,
            cam.cy,
            cam.width,
            cam.height,
            self.config.march_settings(cam),
            values=values,
            color=self.config.nerf_color,
            background=self.config.background,
        )

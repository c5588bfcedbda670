"""Renderer configuration (paper Sec. 3.1 "Preliminaries", NOTES "Depth tuple")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from divas_kernels import render_defaults as RD

if TYPE_CHECKING:
    from divas_kernels import MarchSettings, RasterSettings

    from ..camera import Camera

__all__ = ["RenderConfig"]


@dataclass
class RenderConfig:
    """Constants of both renderers. Defaults are the paper / NOTES values, kept in one
    place: ``divas_kernels.render_defaults`` (also the kernels' own settings defaults).

    Attributes:
        tau_sig: τ_sig — ``D_min`` is the depth of the first element with weight
            ``w_k = α_k T_k ≥ τ_sig``.
        tau_cw: τ_cw — ``D_max`` is the depth at which ``1 − T`` first reaches τ_cw
            (paper Table "NeRF instantiation hyperparameters", 0.75).
        background: RGB added with the final transmittance ``T``.
        t_min: early termination once ``T < t_min`` (1e-4).
        alpha_min: elements with ``α < alpha_min`` (1/255) are skipped (2DGS) / not
            counted in ``N_samp`` (NeRF).
        alpha_max: 2DGS opacity clamp ``α = min(alpha_max, opacity · G)`` (0.99).
        lowpass_sigma: σ of the 2DGS screen-space low-pass filter, pixels (√2/2).
        near: near plane, planar camera depth in world units; a camera with its own
            larger ``Camera.near`` clips there instead (:meth:`Camera.clip_near`).
        tile: rasterizer tile edge, pixels (16).
        max_duplicates: soft cap on (tile, surfel) pairs held at once; the image is
            rendered in bands of tile rows above it (bounds memory on huge scenes).
        blend: rasterizer blend kernel: ``"auto"`` (``tile`` on CPU, ``pixel`` on CUDA).
        nerf_step_scale: NeRF step = ``nerf_step_scale ×`` the smallest voxel edge (½).
        nerf_color: colour of a density grid without an RGB grid (when not shaded).
        shade_grid: colour a density grid without an RGB grid by its shape
            (:mod:`.grid_shading`) instead of ``nerf_color``; None (default): when it was
            read from a format that holds no colour (instant-ngp without its network,
            torch-ngp, a ``.vdb`` without a colour grid).
        nerf_network: draw views of a grid that carries its radiance network (an
            instant-ngp snapshot) from the network (True) or march the grid itself,
            coloured by the network baked at its voxels (False: an order of magnitude
            faster on a CPU); None: the network on CUDA, the grid on a CPU.
        threads: CPU launch threads (None: all usable cores).
        profile: synchronise after each stage and put stage seconds in ``RenderBuffers.stats``.
    """

    tau_sig: float = RD.TAU_SIG
    tau_cw: float = RD.TAU_CW
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    t_min: float = RD.T_MIN
    alpha_min: float = RD.ALPHA_MIN
    alpha_max: float = RD.ALPHA_MAX
    lowpass_sigma: float = RD.LOWPASS_SIGMA
    near: float = RD.NEAR
    tile: int = RD.TILE
    max_duplicates: int = RD.MAX_DUPLICATES
    blend: str = RD.BLEND
    nerf_step_scale: float = RD.NERF_STEP_SCALE
    nerf_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    shade_grid: bool | None = None
    nerf_network: bool | None = None
    threads: int | None = None
    profile: bool = False

    def raster_settings(self, camera: Camera | None = None) -> RasterSettings:
        """The surfel rasterizer's settings for ``camera`` (its near: ``clip_near``)."""
        from divas_kernels import RasterSettings

        return RasterSettings(
            tau_sig=self.tau_sig,
            tau_cw=self.tau_cw,
            t_min=self.t_min,
            alpha_min=self.alpha_min,
            alpha_max=self.alpha_max,
            lowpass_sigma=self.lowpass_sigma,
            near=self._near(camera),
            tile=self.tile,
            max_duplicates=self.max_duplicates,
            blend=self.blend,
            threads=self.threads,
            profile=self.profile,
        )

    def march_settings(self, camera: Camera | None = None) -> MarchSettings:
        """The density-grid ray-marcher's settings for ``camera``."""
        from divas_kernels import MarchSettings

        return MarchSettings(
            tau_sig=self.tau_sig,
            tau_cw=self.tau_cw,
            t_min=self.t_min,
            alpha_min=self.alpha_min,
            near=self._near(camera),
            step_scale=self.nerf_step_scale,
            threads=self.threads,
        )

    def _near(self, camera: Camera | None) -> float:
        return self.near if camera is None else camera.clip_near(self.near)

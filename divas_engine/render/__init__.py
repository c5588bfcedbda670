"""Renderers: one base class, a 2DGS rasterizer, a density-grid ray-marcher and a marcher
of instant-ngp radiance networks (paper Sec. 3.1).

``make_renderer(scene, device)`` picks the adapter for the scene type; everything
downstream sees only :class:`Renderer` and :class:`RenderBuffers`.
"""

from __future__ import annotations

from ..scene import DensityGrid, SurfelScene
from .buffers import DEPTH_CHANNELS, NPZ_CHANNELS, RenderBuffers
from .config import RenderConfig
from .protocol import Renderer

__all__ = [
    "Renderer",
    "RenderBuffers",
    "RenderConfig",
    "make_renderer",
    "SurfelRenderer",
    "NerfRenderer",
    "DEPTH_CHANNELS",
    "NPZ_CHANNELS",
]


def make_renderer(
    scene: SurfelScene | DensityGrid, device=None, config: RenderConfig | None = None
) -> Renderer:
    """The renderer for ``scene`` on ``device`` (``None``/``"auto"``: CUDA if present, else CPU)."""
    if isinstance(scene, SurfelScene):
        from .surfel_renderer import SurfelRenderer

        return SurfelRenderer(scene, device=device, config=config)
    if isinstance(scene, DensityGrid):
        from .ngp_renderer import NgpRenderer, has_ngp_network

        if has_ngp_network(scene) and (config is None or config.nerf_network):
            return NgpRenderer(scene, device=device, config=config)
        from .nerf_renderer import NerfRenderer

        return NerfRenderer(scene, device=device, config=config)
    raise TypeError(f"make_renderer: unsupported scene type {type(scene).__name__}")


def __getattr__(name: str):
    if name == "SurfelRenderer":
        from .surfel_renderer import SurfelRenderer

        return SurfelRenderer
    if name == "NerfRenderer":
        from .nerf_renderer import NerfRenderer

        return NerfRenderer
    raise AttributeError(name)

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
    "network_views",
    "SurfelRenderer",
    "NerfRenderer",
    "DEPTH_CHANNELS",
    "NPZ_CHANNELS",
]


def network_views(config: RenderConfig | None, device=None) -> bool:
    """Whether a snapshot's views come from its network: ``config.nerf_network``, or when
    that is None, on CUDA only (a CPU marches the grid with the network's colour baked:
    seconds per network view there against a fraction of one)."""
    choice = None if config is None else config.nerf_network
    if choice is not None:
        return bool(choice)
    from divas_kernels import resolve_device

    return bool(resolve_device(device).is_cuda)


def make_renderer(
    scene: SurfelScene | DensityGrid, device=None, config: RenderConfig | None = None
) -> Renderer:
    """The renderer for ``scene`` on ``device`` (``None``/``"auto"``: CUDA if present, else CPU)."""
    if isinstance(scene, SurfelScene):
        from .surfel_renderer import SurfelRenderer

        return SurfelRenderer(scene, device=device, config=config)
    if isinstance(scene, DensityGrid):
        from .ngp_renderer import NgpRenderer, has_ngp_network

        if has_ngp_network(scene) and network_views(config, device):
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

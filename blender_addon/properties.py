"""Per-scene session settings (``scene.divas``): what the panel's sliders edit and
:func:`session_config` turns into the engine's frozen :class:`SessionConfig`.

Blender stores float properties in single precision; :func:`_typed` turns each one back
into the shortest decimal that rounds to it (``0.3`` stays ``0.3``), so a slider left at
its default gives exactly the engine's default constant.
"""

from __future__ import annotations

from dataclasses import replace

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from divas_engine.fusion import GridConfig, GsFusionConfig
from divas_engine.mapping import MappingConfig
from divas_engine.render import RenderConfig
from divas_engine.session import SessionConfig

#: how a snapshot's views are drawn (``RenderConfig.nerf_network``: None, True, False)
NERF_VIEWS = [
    ("AUTO", "Auto", "From the network on a CUDA device, from the grid on a CPU"),
    ("NETWORK", "Network", "From the snapshot's network (seconds per view on a CPU)"),
    ("GRID", "Grid", "March the density grid with the network's colour baked in (fast)"),
]
_NERF_NETWORK = {"AUTO": None, "NETWORK": True, "GRID": False}

__all__ = [
    "DIVAS_PG_session_settings",
    "PRESETS",
    "CLASSES",
    "register",
    "unregister",
    "scene_settings",
    "session_config",
    "preset_from_cli",
]

_GS, _MAP = GsFusionConfig(), MappingConfig()

PRESETS = (
    ("AUTO", "Auto", "From the training cameras: forward-facing or 360°"),
    ("FORWARD", "Forward-Facing", "LLFF-style capture (2DGS: grid cap 512; NeRF: llff)"),
    ("UNBOUNDED", "360° / Unbounded", "Object-centred capture (2DGS: grid cap 1024; NeRF: mip360)"),
)
#: preset → (2DGS grid config, NeRF preset name); None: chosen by the engine.
_PRESET_CONFIG = {
    "AUTO": (None, None),
    "FORWARD": (GridConfig.forward_facing(), "llff"),
    "UNBOUNDED": (GridConfig(), "mip360"),
}


class DIVAS_PG_session_settings(bpy.types.PropertyGroup):
    """Settings of the next DivAS session started in this scene (defaults: the paper's)."""

    preset: EnumProperty(
        name="Preset",
        items=PRESETS,
        default="AUTO",
        description="Capture type: occupancy-grid cap (2DGS) or fusion preset (NeRF)",
    )
    render_scale: FloatProperty(
        name="Render Scale",
        default=0.5,
        min=0.01,
        max=4.0,
        soft_min=0.1,
        soft_max=1.0,
        description="Views are rendered at this fraction of their camera's resolution",
    )
    nerf_views: EnumProperty(
        name="NeRF Views",
        items=NERF_VIEWS,
        default="AUTO",
        description="How an instant-ngp snapshot's views are drawn",
    )
    see_through_gap: FloatProperty(
        name="See-Through Gap (γ_ST)",
        default=_GS.gamma_st,
        min=0.0,
        soft_max=5.0,
        description="2DGS fusion: see-through gap as a multiple of "
        "the camera distance d_cam (eq. seethrough)",
    )
    surfel_coverage: FloatProperty(
        name="Surfel Coverage (τ_κ)",
        default=_MAP.surfel_coverage,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
        description="2DGS mapping: a surfel is kept when this "
        "fraction of it is covered (eq. final-F)",
    )
    gamma: FloatProperty(
        name="Depth Tolerance (γ)",
        default=_GS.gamma,
        min=0.0,
        soft_max=10.0,
        description="2DGS fusion: base depth tolerance in voxel sizes (eq. tightening)",
    )
    mask_channel: IntProperty(
        name="Mask Channel",
        default=1,
        min=0,
        max=2,
        description="Segmenter output kept (1: the paper's mid granularity)",
    )
    seed: IntProperty(name="Seed", default=0, min=0, description="Segmenter seed")
    autosave: BoolProperty(
        name="Autosave",
        default=True,
        description="Save the session next to the .blend after every "
        "accept (temp folder while unsaved)",
    )


CLASSES = (DIVAS_PG_session_settings,)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.divas = PointerProperty(type=DIVAS_PG_session_settings)


def unregister() -> None:
    if hasattr(bpy.types.Scene, "divas"):
        del bpy.types.Scene.divas
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)


def scene_settings(scene) -> DIVAS_PG_session_settings | None:
    return getattr(scene, "divas", None)


def _typed(v: float) -> float:
    """The decimal a user typed into a single-precision property (``0.3``, not 0.30000001)."""
    return float(str(np.float32(v)))


def preset_from_cli(name: str | None) -> str:
    """``divas segment --preset`` (llff / mip360 / None) → a :data:`PRESETS` key."""
    return {None: "AUTO", "llff": "FORWARD", "mip360": "UNBOUNDED"}[name]


def session_config(props, *, autosave: str | None = None) -> SessionConfig:
    """The engine config of the scene settings ``props`` (None: the engine's defaults,
    with the panel's default render scale)."""
    if props is None:
        return SessionConfig(render_scale=0.5, autosave=autosave)
    grid, nerf = _PRESET_CONFIG[props.preset]
    gs = replace(_GS, gamma=_typed(props.gamma), gamma_st=_typed(props.see_through_gap))
    mapping = replace(_MAP, surfel_coverage=_typed(props.surfel_coverage))
    return SessionConfig(
        render_scale=_typed(props.render_scale),
        grid=grid,
        gs_fusion=gs,
        nerf_preset=nerf,
        mapping=mapping,
        mask_channel=int(props.mask_channel),
        seed=int(props.seed),
        autosave=autosave,
        render=replace(RenderConfig(), nerf_network=_NERF_NETWORK[props.nerf_views]),
    )

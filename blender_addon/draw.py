"""Draws DivAS's feedback over every 3D view with the ``gpu`` module (the geometry is
:mod:`.overlays`; this module only collects it for the region being drawn and hands it
to the GPU).

Two ``SpaceView3D`` draw handlers: ``POST_VIEW`` (world space: the selection tint, the
preview in 3D, the clicked points) and ``POST_PIXEL`` (region space: over a DivAS
camera's frame, the mask preview, the selection overlay and the prompt points; the
rubber band of a selection gesture). They draw after the scene, so nothing the object
draws covers them, in every shading mode. Batches and textures are cached by what they
show (the session's version, the selection array), so a redraw that changes nothing
uploads nothing.

Headless Blender cannot draw: :func:`pixel_items` and :func:`view_items` (what would be
drawn) are what the tests check; a person checks the pixels in a real window.
"""

from __future__ import annotations

import numpy as np

from . import overlays, session_registry, source
from .preferences import get_preferences

__all__ = [
    "register",
    "unregister",
    "pixel_items",
    "view_items",
    "touch",
    "add_gesture_handler",
    "remove_handler",
]

_handles: list[tuple] = []
_generation = [0]  # bumped when points change outside a session (undo, manual edits)
_cache: dict[tuple, object] = {}
_CACHE_MAX = 64


def touch() -> None:
    """Something drawn changed outside a session's steps: rebuild the cached items."""
    _generation[0] += 1
    _cache.clear()


def _prefs(context):
    p = get_preferences(context)
    return (
        bool(getattr(p, "show_render", False)),
        bool(getattr(p, "show_selection", True)),
        float(getattr(p, "tint_point_size", 3.0)),
    )


# ----------------------------------------------------------------------------- what to draw
def pixel_items(context) -> list:
    """Region-space items over the DivAS camera the region looks through (none in a free
    view or through another camera)."""
    from .session_actions import camera_target
    from .view3d import camera_frame_in_region

    rv3d, region, scene = context.region_data, context.region, context.scene
    if rv3d is None or scene is None or getattr(rv3d, "view_perspective", "") != "CAMERA":
        return []
    cam = scene.camera
    for live in session_registry.all_sessions():
        target = camera_target(live, cam)
        if target.is_anchor or target.is_view:
            if target.is_anchor:
                from .handlers import request_background_fill

                request_background_fill()  # a lazy anchor: its render comes by timer
            frame = camera_frame_in_region(region, rv3d, scene, cam)
            if frame is None:
                return []
            show_render = _prefs(context)[0]
            key = ("camera", live.key, live.version, _generation[0], cam.name, show_render)
            return _cached(
                key + (np.round(frame, 3).tobytes(),),
                lambda lv=live, t=target, f=frame, r=show_render: overlays.camera_items(
                    lv, t, f, show_render=r
                ),
            )
    return []


def _cached(key: tuple, make):
    if key not in _cache:
        if len(_cache) >= _CACHE_MAX:
            _cache.clear()
        _cache[key] = make()
    return _cache[key]


def view_items(context) -> list[tuple[np.ndarray, overlays.Points3D]]:
    """``(object matrix, item)`` pairs, items in object space: every visible DivAS
    object's selection tint and, for objects with a session, its clicks and 3D preview."""
    from divas_engine.point_attributes import SELECTED

    from . import bridge

    show_selection, size = _prefs(context)[1:]
    out = []
    for obj in context.scene.objects if context.scene is not None else ():
        if source.source_of(obj) is None or not obj.visible_get():
            continue
        live = session_registry.get(obj)
        geom = obj.data
        key = (obj.name, geom.name, None if live is None else live.version, _generation[0])
        mw = np.array(obj.matrix_world, np.float64)
        pos = _cached(key + ("positions",), lambda g=geom: bridge.read_attribute(g, "position"))
        if show_selection and geom.attributes.get(SELECTED) is not None:
            item = _cached(
                key + ("tint",),
                lambda g=geom, k=key, p=pos: overlays.selection_points(
                    p, bridge.read_attribute(g, SELECTED), np.eye(4), k + ("tint",)
                ),
            )
            if item is not None:
                out.append((mw, overlays.Points3D(item.positions, item.color, size, item.key)))
        if live is not None:
            items = _cached(
                key + ("scene",), lambda lv=live, p=pos: overlays.scene_items(lv, p, np.eye(4))
            )
            out += [(mw, it) for it in items]
    return out


# ----------------------------------------------------------------------------- GPU calls
def _texture(item: overlays.ImageQuad):
    import gpu

    def make():
        h, w = item.rgba.shape[:2]
        data = overlays.texture_rows(item.rgba)
        try:
            buf = gpu.types.Buffer("FLOAT", data.size, data)
        except TypeError:  # a build without the buffer protocol here
            buf = gpu.types.Buffer("FLOAT", data.size, data.tolist())
        return gpu.types.GPUTexture((w, h), format="RGBA32F", data=buf)

    # keyed by the cached item's own array: alive (so its id is unique) while cached
    return _cached(("texture", id(item.rgba)), make)


def _draw_pixel() -> None:
    import bpy
    import gpu
    from gpu_extras.batch import batch_for_shader

    items = pixel_items(bpy.context)
    if not items:
        return
    gpu.state.blend_set("ALPHA")
    for item in items:
        if isinstance(item, overlays.ImageQuad):
            shader = gpu.shader.from_builtin("IMAGE")
            batch = batch_for_shader(
                shader,
                "TRIS",
                {"pos": item.corners.astype(np.float32), "texCoord": overlays.QUAD_UV},
                indices=overlays.QUAD_TRIANGLES,
            )
            shader.bind()
            shader.uniform_sampler("image", _texture(item))
            batch.draw(shader)
        elif isinstance(item, overlays.Markers):
            pos, col = overlays.disc_triangles(item)
            shader = gpu.shader.from_builtin("SMOOTH_COLOR")
            batch_for_shader(shader, "TRIS", {"pos": pos, "color": col}).draw(shader)
    gpu.state.blend_set("NONE")


def _draw_view() -> None:
    import bpy
    import gpu
    from gpu_extras.batch import batch_for_shader

    items = view_items(bpy.context)
    if not items:
        return
    shader = gpu.shader.from_builtin("POINT_UNIFORM_COLOR")
    gpu.state.blend_set("ALPHA")
    gpu.state.depth_test_set("NONE")  # over the splats: the feedback is never hidden
    for mw, item in items:
        batch = _cached(
            ("batch", *item.key, len(item.positions)),
            lambda item=item: batch_for_shader(shader, "POINTS", {"pos": item.positions}),
        )
        gpu.matrix.push()
        gpu.matrix.multiply_matrix(_matrix(mw))
        gpu.state.point_size_set(item.size)
        shader.bind()
        shader.uniform_float("color", item.color)
        batch.draw(shader)
        gpu.matrix.pop()
    gpu.state.point_size_set(1.0)
    gpu.state.blend_set("NONE")


def _matrix(m: np.ndarray):
    from mathutils import Matrix

    return Matrix(m.tolist())


def _draw_gesture(gesture) -> None:
    import gpu
    from gpu_extras.batch import batch_for_shader

    outline = overlays.gesture_outline(gesture.shape, gesture.points, gesture.radius)
    if len(outline) < 2:
        return
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.blend_set("ALPHA")
    shader.bind()
    shader.uniform_float("color", (1.0, 1.0, 1.0, 0.9))
    batch_for_shader(shader, "LINE_LOOP", {"pos": outline}).draw(shader)
    gpu.state.blend_set("NONE")


# ----------------------------------------------------------------------------- handlers
def add_gesture_handler(gesture):
    import bpy

    return bpy.types.SpaceView3D.draw_handler_add(_draw_gesture, (gesture,), "WINDOW", "POST_PIXEL")


def remove_handler(handle) -> None:
    import bpy

    if handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(handle, "WINDOW")


def register() -> None:
    import bpy

    unregister()
    space = bpy.types.SpaceView3D
    _handles.append(space.draw_handler_add(_draw_view, (), "WINDOW", "POST_VIEW"))
    _handles.append(space.draw_handler_add(_draw_pixel, (), "WINDOW", "POST_PIXEL"))


def unregister() -> None:
    while _handles:
        remove_handler(_handles.pop())
    _cache.clear()

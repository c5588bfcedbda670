"""What DivAS draws over the 3D viewport, as plain geometry (no ``gpu``: :mod:`.draw`
turns these items into GPU batches inside Blender's draw callbacks).

Feedback is drawn *over* the scene, so the object's own points never hide it, in every
shading mode:

* looking through a DivAS camera (``POST_PIXEL``, region coordinates): the view's mask
  preview (blue) stretched over the camera frame, the engine's selection overlay on the
  view (Sec. 3.7; orange, while that selection is current), the prompt points / anchor
  clicks as discs (green positive, red negative), optionally the engine's own render
  under them (what the segmenter sees);
* in every 3D view (``POST_VIEW``, world coordinates): the selected points (orange
  tint), the points under an open view's mask preview (blue: the preview in 3D), and the
  clicked 3D points as markers.

Camera images map to the region through the camera frame's corners
(:func:`divas_engine.viewport.camera_pixel_to_region`), so a marker lies on the pixel it
was clicked at. A camera's *background* image is the engine's plain render
(:func:`set_background`), packed into the .blend so it survives saving (at the next idle
moment, and at the latest before a save).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_engine.kinds import ViewStatus
from divas_engine.selection_tools import points_under_mask
from divas_engine.viewport import camera_pixel_to_region

from . import bridge
from .modal_logic import Target

__all__ = [
    "PREVIEW_COLOR",
    "PREVIEW_ALPHA",
    "SELECTION_COLOR",
    "POSITIVE_COLOR",
    "NEGATIVE_COLOR",
    "ImageQuad",
    "Markers",
    "Points3D",
    "mask_rgba",
    "camera_items",
    "scene_items",
    "selection_points",
    "set_background",
    "image_name",
]

#: the 2D mask preview (blue, so it is not mistaken for the 3D selection's orange).
PREVIEW_COLOR, PREVIEW_ALPHA = (0.15, 0.55, 1.0), 0.45
SELECTION_COLOR = (1.0, 0.35, 0.05)
POSITIVE_COLOR, NEGATIVE_COLOR = (0.1, 0.95, 0.2), (1.0, 0.1, 0.1)


@dataclass(frozen=True, eq=False)
class ImageQuad:
    """An RGBA image (``[H,W,4]`` float32, top row first) stretched over a region quad
    (``corners`` ``[4,2]`` in ``view_frame`` order: top-right, bottom-right,
    bottom-left, top-left); ``key`` names the image for texture caching."""

    corners: np.ndarray
    rgba: np.ndarray
    key: tuple


@dataclass(frozen=True, eq=False)
class Markers:
    """Discs of ``radius`` region pixels at ``xy`` ``[N,2]`` with ``colors`` ``[N,4]``
    (a dark rim is drawn around each)."""

    xy: np.ndarray
    colors: np.ndarray
    radius: float


@dataclass(frozen=True, eq=False)
class Points3D:
    """World-space points ``[N,3]`` drawn as ``size``-pixel dots of ``color`` (RGBA)."""

    positions: np.ndarray
    color: tuple[float, float, float, float]
    size: float
    key: tuple


def mask_rgba(mask: np.ndarray, color, alpha: float) -> np.ndarray:
    """``[H,W,4]``: ``color`` everywhere, alpha ``alpha · clip(mask, 0, 1)``."""
    m = np.clip(np.asarray(mask, np.float32), 0.0, 1.0)
    out = np.empty((*m.shape, 4), np.float32)
    out[..., :3] = np.asarray(color, np.float32)
    out[..., 3] = m * np.float32(alpha)
    return out


def _markers(points, labels, frame, size, radius: float) -> Markers | None:
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if not len(pts):
        return None
    xy = camera_pixel_to_region(pts, frame, size)
    colors = np.array(
        [(*(POSITIVE_COLOR if int(b) == 1 else NEGATIVE_COLOR), 1.0) for b in np.ravel(labels)],
        np.float32,
    )
    return Markers(xy, colors, radius)


def _view_prompts(session, v) -> tuple[np.ndarray, np.ndarray]:
    if v.preview is not None and v.status != ViewStatus.FUSED:
        return v.preview.points, v.preview.labels
    if v.points is not None:
        return v.points, v.labels
    return session.default_prompts(v)


def camera_items(
    live, target: Target, frame: np.ndarray, *, show_render: bool = False, radius: float = 6.0
) -> list:
    """What to draw over a DivAS camera showing ``target`` of ``live``'s session, whose
    frame lies at ``frame`` in the region (``[4,2]``, ``view_frame`` order)."""
    s = live.session
    items: list = []
    if target.is_view:
        try:
            v = s.view(target.view_id)
        except KeyError:
            return items
        size = (v.camera.width, v.camera.height)
        if show_render:
            rgb = s.render(v).rgb
            rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], 2)
            items.append(ImageQuad(frame, rgba, ("render", v.id)))
        mask = v.mask if v.status == ViewStatus.FUSED else (v.preview and v.preview.mask)
        if mask is not None:
            key = ("mask", v.id, id(mask))
            items.append(ImageQuad(frame, mask_rgba(mask, PREVIEW_COLOR, PREVIEW_ALPHA), key))
        cov = live.coverage_of(v.id)  # rendered here on the view's first draw
        if cov is not None:
            key = ("coverage", v.id, id(cov))
            items.append(ImageQuad(frame, mask_rgba(cov, SELECTION_COLOR, 0.5), key))
        pts, labs = _view_prompts(s, v)
        m = _markers(pts, labs, frame, size, radius)
        if m is not None:
            items.append(m)
    elif target.is_anchor and 0 <= target.anchor < len(s.anchors):
        a = s.anchors[target.anchor]
        size = (a.camera.width, a.camera.height)
        if show_render:
            rgb = s.render(a).rgb
            rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], 2)
            items.append(ImageQuad(frame, rgba, ("render", "anchor", target.anchor)))
        clicks = s.current.clicks.get(target.anchor, [])
        m = _markers([c.xy for c in clicks], [int(c.positive) for c in clicks], frame, size, radius)
        if m is not None:
            items.append(m)
    return items


def _world(points: np.ndarray, matrix_world: np.ndarray) -> np.ndarray:
    p = np.asarray(points, np.float64).reshape(-1, 3)
    m = np.asarray(matrix_world, np.float64)
    return (p @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


def selection_points(
    positions: np.ndarray, selected: np.ndarray, matrix_world: np.ndarray, key: tuple
) -> Points3D | None:
    """The selected points in world space, drawn as the orange selection tint."""
    sel = np.asarray(selected, bool)
    if not sel.any():
        return None
    pts = _world(np.asarray(positions)[sel], matrix_world)
    return Points3D(pts, (*SELECTION_COLOR, 0.85), 3.0, key)


def scene_items(live, positions: np.ndarray, matrix_world: np.ndarray) -> list[Points3D]:
    """3D feedback of ``live``'s session in any view: the clicked points of the current
    object and, for each open view with a preview, the points under its mask (the preview
    in 3D: :func:`~divas_engine.selection_tools.points_under_mask`). ``positions``: the
    object's points in the scene frame."""
    s = live.session
    items: list[Points3D] = []
    for label, color in ((True, POSITIVE_COLOR), (False, NEGATIVE_COLOR)):
        pts = [
            c.point
            for cs in s.current.clicks.values()
            for c in cs
            if c.positive is label and c.point is not None
        ]
        if pts:
            items.append(
                Points3D(
                    _world(np.array(pts), matrix_world), (*color, 1.0), 12.0, ("clicks", label)
                )
            )
    for v in s.views:
        prev = v.preview
        if v.status == ViewStatus.FUSED or prev is None or prev.mask is None:
            continue
        under = points_under_mask(positions, v.camera, prev.mask, s.render(v).D_ref)
        if under.any():
            pts = _world(np.asarray(positions)[under], matrix_world)
            items.append(Points3D(pts, (*PREVIEW_COLOR, 0.9), 3.0, ("preview", v.id, id(prev))))
    return items


# ----------------------------------------------------------------------------- backgrounds
def image_name(cam_obj) -> str:
    return f"DivAS {cam_obj.name}"


def set_background(cam_obj, rgb: np.ndarray, *, alpha: float = 1.0):
    """Show the engine render ``rgb`` (``[H,W,3]``, top row first) behind ``cam_obj``'s
    view: one image per camera, packed into the .blend (so it survives saving and
    reopening: at the next idle moment and at the latest before a save,
    :func:`.bridge.pack_soon`; the feedback is drawn over it by :mod:`.draw`)."""
    rgb = np.asarray(rgb, np.float32)
    rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)
    img = bridge.write_image(image_name(cam_obj), rgba)
    bridge.pack_soon(img)
    data = cam_obj.data
    bg = data.background_images[0] if len(data.background_images) else data.background_images.new()
    bg.source = "IMAGE"
    bg.image = img
    bg.frame_method = "STRETCH"
    bg.display_depth = "BACK"
    bg.alpha = alpha
    bg.show_background_image = True
    data.show_background_images = True
    return img


# ----------------------------------------------------------------------------- GPU geometry
#: a quad's two triangles over ``view_frame``-ordered corners (TR, BR, BL, TL), and the
#: texture coordinates of those corners (GPU textures start at the bottom row).
QUAD_TRIANGLES = ((0, 1, 2), (0, 2, 3))
QUAD_UV = ((1.0, 1.0), (1.0, 0.0), (0.0, 0.0), (0.0, 1.0))
_RIM = (0.05, 0.05, 0.05, 1.0)


def texture_rows(rgba: np.ndarray) -> np.ndarray:
    """``rgba`` (top row first) as a GPU texture's flat float32 data (bottom row first)."""
    return np.ascontiguousarray(np.asarray(rgba, np.float32)[::-1]).reshape(-1)


def disc_triangles(markers: Markers, segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """``(positions [M,2], colors [M,4])`` of triangles drawing each marker as a disc
    with a dark rim (rim first, so the disc is drawn over it)."""
    ang = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    pos, col = [], []
    for (x, y), c in zip(np.asarray(markers.xy, np.float64), np.asarray(markers.colors)):
        for r, color in ((markers.radius + 1.5, _RIM), (markers.radius, tuple(c))):
            pts = np.array([x, y]) + r * ring
            for k in range(segments):
                pos += [(x, y), tuple(pts[k]), tuple(pts[k + 1])]
                col += [color] * 3
    return np.array(pos, np.float32).reshape(-1, 2), np.array(col, np.float32).reshape(-1, 4)


def gesture_outline(shape: str, points, radius: float, segments: int = 48) -> np.ndarray:
    """``[K,2]`` region points of the gesture's outline (a closed line loop)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if shape == "BOX" and len(pts) == 2:
        (x0, y0), (x1, y1) = pts
        return np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], np.float32)
    if shape == "CIRCLE" and len(pts) >= 1:
        ang = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
        return (pts[-1] + radius * np.stack([np.cos(ang), np.sin(ang)], 1)).astype(np.float32)
    return pts.astype(np.float32)

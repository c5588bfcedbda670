"""What a DivAS camera shows behind the scene: its engine render, with the mask preview
and the prompt points, or the 3D selection overlay, as the camera's background image.

Compositing is plain NumPy on the ``[H,W,3]`` renders the session already holds (the
selection overlay itself comes composited from the engine, :meth:`Session.overlay`);
the image crosses into Blender once, through :func:`.bridge.write_image`, and is shown
with ``frame_method = 'STRETCH'`` so image pixel (u, v) lies exactly on the camera's
pixel (u, v) (the camera frame has the image's size and pixel aspect).
"""

from __future__ import annotations

import numpy as np

from . import bridge

__all__ = [
    "PREVIEW_COLOR",
    "PREVIEW_ALPHA",
    "POSITIVE_COLOR",
    "NEGATIVE_COLOR",
    "tint",
    "draw_points",
    "preview_image",
    "set_background",
    "image_name",
]

#: the 2D mask preview (blue, so it is not mistaken for the 3D selection's orange).
PREVIEW_COLOR, PREVIEW_ALPHA = (0.15, 0.55, 1.0), 0.45
POSITIVE_COLOR, NEGATIVE_COLOR = (0.1, 0.95, 0.2), (1.0, 0.1, 0.1)


def tint(rgb: np.ndarray, weight: np.ndarray, color, alpha: float) -> np.ndarray:
    """``rgb`` ``[H,W,3]`` mixed towards ``color`` by ``alpha · clip(weight, 0, 1)``."""
    a = (np.clip(np.asarray(weight, np.float32), 0.0, 1.0) * np.float32(alpha))[..., None]
    return (rgb * (1.0 - a) + np.asarray(color, np.float32) * a).astype(np.float32)


def draw_points(rgb: np.ndarray, points, labels, radius: float | None = None) -> np.ndarray:
    """Discs at prompt points (continuous pixels): green positive, red negative, with a
    dark rim so they read on any background."""
    out = np.array(rgb, dtype=np.float32, copy=True)
    h, w = out.shape[:2]
    r = radius if radius is not None else max(2.0, 0.008 * max(h, w))
    yy, xx = np.mgrid[0:h, 0:w]
    cx, cy = xx + 0.5, yy + 0.5
    for (x, y), lab in zip(np.asarray(points, np.float64).reshape(-1, 2), np.ravel(labels)):
        d2 = (cx - x) ** 2 + (cy - y) ** 2
        out[d2 <= (r + 1.0) ** 2] = 0.0
        out[d2 <= r * r] = POSITIVE_COLOR if int(lab) == 1 else NEGATIVE_COLOR
    return out


def preview_image(rgb: np.ndarray, mask: np.ndarray | None, points=None, labels=None) -> np.ndarray:
    """A view's render with the depth-weighted mask preview and its prompt points."""
    out = rgb if mask is None else tint(rgb, mask, PREVIEW_COLOR, PREVIEW_ALPHA)
    if points is not None and len(points):
        out = draw_points(out, points, labels)
    return np.asarray(out, np.float32)


def image_name(cam_obj) -> str:
    return f"DivAS {cam_obj.name}"


def set_background(cam_obj, rgb: np.ndarray, *, alpha: float = 1.0):
    """Show ``rgb`` (``[H,W,3]``, top row first) behind ``cam_obj``'s view (one image per
    camera, updated in place)."""
    rgb = np.asarray(rgb, np.float32)
    rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)
    img = bridge.write_image(image_name(cam_obj), rgba)
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

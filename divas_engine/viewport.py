"""Viewport click → camera pixel, in pure NumPy (no ``bpy``).

Looking through a camera, Blender draws the camera frame as a quadrilateral in *region*
coordinates (origin bottom-left, y up); its corners are the image corners, so region → image is
the homography fixed by those four correspondences (affine when the frame is axis-aligned;
letterboxing and pixel aspect need no special case). A click is taken at its region pixel's
centre (+0.5). A free 3D view is a camera too (:func:`camera_from_region`): from the
perspective ``window_matrix`` ``P``, ``fx = W P₀₀ / 2``, ``cx = W (1 − P₀₂) / 2``,
``fy = H P₁₁ / 2``, ``cy = H (1 + P₁₂) / 2`` and ``c2w = view_matrix⁻¹ · diag(1, −1, −1, 1)``;
an orthographic view has no pinhole camera. The derivation: docs/design-notes.md.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "frame_image_corners",
    "frame_homography",
    "region_to_camera_pixel",
    "camera_pixel_to_region",
    "OrthographicViewError",
    "camera_from_region",
    "region_matrices",
    "region_click_pixel",
]


def frame_image_corners(width: int, height: int) -> np.ndarray:
    """``[4,2]`` image corners matching ``view_frame`` order (TR, BR, BL, TL), engine pixels."""
    w, h = float(width), float(height)
    return np.array([[w, 0.0], [w, h], [0.0, h], [0.0, 0.0]])


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``[3,3]`` H with ``dst ~ H · src`` for four point pairs (direct linear transform)."""
    a = np.zeros((8, 8))
    b = np.zeros(8)
    for k, ((x, y), (u, v)) in enumerate(zip(src, dst)):
        a[2 * k] = [x, y, 1, 0, 0, 0, -u * x, -u * y]
        a[2 * k + 1] = [0, 0, 0, x, y, 1, -v * x, -v * y]
        b[2 * k], b[2 * k + 1] = u, v
    try:
        h = np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        raise ValueError("camera frame corners are degenerate (collinear or coincident)") from None
    return np.append(h, 1.0).reshape(3, 3)


def _check_frame(frame_corners) -> np.ndarray:
    c = np.asarray(frame_corners, dtype=np.float64)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise ValueError(f"frame_corners must be 4 finite (x, y) region points, got {c.shape}")
    return c


def frame_homography(frame_corners, image_size: tuple[int, int]) -> np.ndarray:
    """``[3,3]`` map from region coordinates to continuous camera pixels.

    Args:
        frame_corners: ``[4,2]`` camera frame corners in region coordinates, in
            ``view_frame`` order (top-right, bottom-right, bottom-left, top-left).
        image_size: camera image ``(width, height)`` in pixels.
    """
    w, h = image_size
    if int(w) <= 0 or int(h) <= 0:
        raise ValueError(f"empty camera image {w}x{h}")
    return _homography(_check_frame(frame_corners), frame_image_corners(w, h))


def region_to_camera_pixel(
    region_size: tuple[int, int],
    frame_corners,
    mouse_region: tuple[float, float],
    image_size: tuple[int, int],
) -> tuple[float, float] | None:
    """Continuous camera pixel ``(u, v)`` (+0.5 centres, y down) under a viewport click.

    Args:
        region_size: ``(region.width, region.height)``; a click outside it gives None.
        frame_corners: ``[4,2]`` camera frame in region coordinates (``view_frame`` order:
            top-right, bottom-right, bottom-left, top-left).
        mouse_region: ``(event.mouse_region_x, event.mouse_region_y)``, integer region
            pixel; the click is taken at its centre (+0.5).
        image_size: camera image ``(width, height)``.

    Returns:
        ``(u, v)`` with ``0 ≤ u < W``, ``0 ≤ v < H``, or None when the click is outside
        the region or outside the camera frame (e.g. in the letterbox / passepartout).
    """
    rw, rh = region_size
    mx, my = float(mouse_region[0]), float(mouse_region[1])
    if not (0 <= mx < rw and 0 <= my < rh):
        return None
    hmat = frame_homography(frame_corners, image_size)
    p = hmat @ np.array([mx + 0.5, my + 0.5, 1.0])
    if p[2] <= 0:  # behind the frame's plane (cannot happen through the camera)
        return None
    u, v = p[0] / p[2], p[1] / p[2]
    w, h = image_size
    if not (0.0 <= u < w and 0.0 <= v < h):
        return None
    return float(u), float(v)


def camera_pixel_to_region(uv, frame_corners, image_size: tuple[int, int]) -> np.ndarray:
    """``[N,2]`` region coordinates of continuous camera pixels (inverse map, for overlays)."""
    hinv = np.linalg.inv(frame_homography(frame_corners, image_size))
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    p = np.concatenate([uv, np.ones((len(uv), 1))], 1) @ hinv.T
    return p[:, :2] / p[:, 2:3]


#: Blender camera axes (−z forward, y up) ↔ OpenCV axes, right-multiplied on a
#: camera-to-world matrix (the same matrix as ``blender_convention.BLENDER_TO_OPENCV``;
#: a sibling layer, so not imported).
BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


class OrthographicViewError(ValueError):
    """The 3D view is orthographic: it has no pinhole camera to click through."""


def camera_from_region(view_matrix, window_matrix, region_size: tuple[int, int], name: str = ""):
    """The exact pinhole :class:`~divas_engine.camera.Camera` (OpenCV, world frame) of a
    perspective 3D-view region (module docstring), image size = the region's size.

    Raises:
        OrthographicViewError: the view is orthographic.
        ValueError: a singular view matrix or an empty region.
    """
    from .camera import Camera

    vm = np.asarray(view_matrix, np.float64).reshape(4, 4)
    p = np.asarray(window_matrix, np.float64).reshape(4, 4)
    w, h = int(region_size[0]), int(region_size[1])
    if w <= 0 or h <= 0:
        raise ValueError(f"empty region {w}x{h}")
    if abs(p[3, 3]) > 1e-9 or abs(p[3, 2] + 1.0) > 1e-6:
        raise OrthographicViewError("the 3D view is orthographic, not a perspective view")
    try:
        c2w = np.linalg.inv(vm)
    except np.linalg.LinAlgError:
        raise ValueError("the 3D view's view matrix is singular") from None
    r = c2w[:3, :3]
    c2w[:3, :3] = r / np.linalg.norm(r, axis=0, keepdims=True)  # float32 round-off
    return Camera(
        w,
        h,
        0.5 * w * p[0, 0],
        0.5 * h * p[1, 1],
        0.5 * w * (1.0 - p[0, 2]),
        0.5 * h * (1.0 + p[1, 2]),
        c2w @ BLENDER_TO_OPENCV,
        name,
    )


def region_matrices(camera, near: float = 0.01, far: float = 1000.0):
    """``(view_matrix, window_matrix)`` of a 3D-view region of the camera's image size
    that shows exactly ``camera`` (the inverse of :func:`camera_from_region`)."""
    vm = np.linalg.inv(camera.c2w @ BLENDER_TO_OPENCV)
    w, h = camera.width, camera.height
    p = np.zeros((4, 4))
    p[0, 0], p[0, 2] = 2.0 * camera.fx / w, 1.0 - 2.0 * camera.cx / w
    p[1, 1], p[1, 2] = 2.0 * camera.fy / h, 2.0 * camera.cy / h - 1.0
    p[2, 2], p[2, 3] = -(far + near) / (far - near), -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return vm, p


def region_click_pixel(mouse_region: tuple[float, float], region_size: tuple[int, int]):
    """The image pixel ``(u, v)`` of the region's own camera under a click at integer
    region pixel ``mouse_region`` (its centre: ``+0.5``; y flipped)."""
    mx, my = float(mouse_region[0]), float(mouse_region[1])
    return mx + 0.5, float(region_size[1]) - (my + 0.5)

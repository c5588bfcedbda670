"""Engine :class:`~divas_engine.camera.Camera` ↔ Blender camera, in pure NumPy (no ``bpy``).

Blender semantics (``BKE_camera_params_compute_viewplane`` in ``blenkernel/intern/camera.cc``;
``bpy_extras.object_utils.world_to_camera_view``): ``matrix_world = c2w_opencv ·
diag(1, −1, −1, 1)``; ``ycor = pixel_aspect_y / pixel_aspect_x``; the fitted dimension is
``viewfac = W`` (horizontal) or ``ycor · H`` (vertical), ``'AUTO'`` always using
``sensor_width``; ``fx = lens · viewfac / sensor``, ``fy = fx / ycor``; shift is a fraction of
the fitted dimension, ``cx = W/2 − shift_x · viewfac``, ``cy = H/2 + shift_y · viewfac / ycor``.
:func:`camera_to_blender` always writes an explicit fit. :func:`axis_conversion` is
``bpy_extras.io_utils.axis_conversion`` in NumPy; :func:`up_conversion` turns an estimated
scene up into the object rotation that makes it Blender's +Z. Details: docs/design-notes.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import Camera

__all__ = [
    "AXES",
    "FORWARD_FOR_UP",
    "axis_vector",
    "axis_conversion",
    "nearest_axis",
    "up_conversion",
    "conversion_matrix",
    "BLENDER_TO_OPENCV",
    "BlenderCameraParams",
    "camera_from_blender",
    "camera_to_blender",
    "project_blender",
    "world_to_camera_view",
]

#: right-multiply a camera-to-world matrix to swap Blender (−z forward, y up) and OpenCV axes.
BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


@dataclass(frozen=True, eq=False)
class BlenderCameraParams:
    """What a ``bpy`` camera object + scene render settings hold for a perspective camera.

    Attributes:
        matrix_world: ``[4,4]`` object matrix (Blender camera axes; scale allowed, ignored).
        lens_mm, sensor_width_mm, sensor_height_mm: ``Camera.lens``, ``sensor_width/height``.
        sensor_fit: ``'AUTO'``, ``'HORIZONTAL'`` or ``'VERTICAL'``.
        shift_x, shift_y: lens shift, fractions of the fitted sensor dimension.
        resolution_x, resolution_y, resolution_percentage: ``scene.render`` size.
        pixel_aspect_x, pixel_aspect_y: ``scene.render.pixel_aspect_x/y``.
        name: camera name (carried through).
    """

    matrix_world: np.ndarray
    lens_mm: float
    sensor_width_mm: float
    sensor_height_mm: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    resolution_x: int
    resolution_y: int
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    resolution_percentage: int = 100
    name: str = field(default="")

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix_world, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"matrix_world must be 4x4, got shape {m.shape}")
        object.__setattr__(self, "matrix_world", m)
        if self.sensor_fit not in _FITS:
            raise ValueError(f"sensor_fit must be one of {_FITS}, got {self.sensor_fit!r}")
        for k in (
            "lens_mm",
            "sensor_width_mm",
            "sensor_height_mm",
            "pixel_aspect_x",
            "pixel_aspect_y",
        ):
            v = float(getattr(self, k))
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{k}={v} must be positive")
        if (
            int(self.resolution_x) <= 0
            or int(self.resolution_y) <= 0
            or int(self.resolution_percentage) <= 0
        ):
            raise ValueError(
                f"empty resolution {self.resolution_x}x{self.resolution_y} "
                f"at {self.resolution_percentage}%"
            )

    @property
    def render_size(self) -> tuple[int, int]:
        """Rendered ``(width, height)`` in pixels (Blender's integer percentage scaling)."""
        pct = int(self.resolution_percentage)
        return int(self.resolution_x) * pct // 100, int(self.resolution_y) * pct // 100

    @property
    def fit(self) -> str:
        """The resolved fit, ``'HORIZONTAL'`` or ``'VERTICAL'`` (``BKE_camera_sensor_fit``)."""
        if self.sensor_fit != "AUTO":
            return self.sensor_fit
        w, h = self.render_size
        return "HORIZONTAL" if w * self.pixel_aspect_x >= h * self.pixel_aspect_y else "VERTICAL"

    @property
    def sensor_mm(self) -> float:
        """Sensor size used for the focal length (``BKE_camera_sensor_size``)."""
        return self.sensor_height_mm if self.sensor_fit == "VERTICAL" else self.sensor_width_mm


def camera_to_blender(cam: Camera, sensor_mm: float = 36.0) -> BlenderCameraParams:
    """Blender settings reproducing ``cam`` exactly (fx ≠ fy: pixel aspect; cx, cy: shift)."""
    w, h = cam.width, cam.height
    ycor = cam.fx / cam.fy  # = pixel_aspect_y / pixel_aspect_x
    aspx, aspy = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    disp_w, disp_h = w * aspx, h * aspy  # image extent in "square" units
    if disp_w >= disp_h:
        fit, viewfac = "HORIZONTAL", float(w)
        sensor_w, sensor_h = sensor_mm, sensor_mm * disp_h / disp_w
        lens = cam.fx * sensor_w / viewfac
    else:
        fit, viewfac = "VERTICAL", ycor * h
        sensor_w, sensor_h = sensor_mm * disp_w / disp_h, sensor_mm
        lens = cam.fx * sensor_h / viewfac
    return BlenderCameraParams(
        matrix_world=cam.c2w @ BLENDER_TO_OPENCV,
        lens_mm=lens,
        sensor_width_mm=sensor_w,
        sensor_height_mm=sensor_h,
        sensor_fit=fit,
        shift_x=(w / 2.0 - cam.cx) / viewfac,
        shift_y=(cam.cy - h / 2.0) * ycor / viewfac,
        resolution_x=w,
        resolution_y=h,
        pixel_aspect_x=aspx,
        pixel_aspect_y=aspy,
        resolution_percentage=100,
        name=cam.name,
    )


def _normalized_matrix(m: np.ndarray) -> np.ndarray:
    """``m`` with unit-length rotation columns (Blender's ``Matrix.normalized()``)."""
    out = np.array(m, dtype=np.float64)
    n = np.linalg.norm(out[:3, :3], axis=0)
    if np.any(n == 0):
        raise ValueError("matrix_world has a zero scale axis")
    out[:3, :3] /= n
    return out


def camera_from_blender(params: BlenderCameraParams) -> Camera:
    """The engine camera of a Blender camera (any sensor fit, shift, pixel aspect, percentage)."""
    w, h = params.render_size
    ycor = params.pixel_aspect_y / params.pixel_aspect_x
    viewfac = float(w) if params.fit == "HORIZONTAL" else ycor * h
    fx = params.lens_mm * viewfac / params.sensor_mm
    fy = fx / ycor
    cx = w / 2.0 - params.shift_x * viewfac
    cy = h / 2.0 + params.shift_y * viewfac / ycor
    c2w = _normalized_matrix(params.matrix_world) @ BLENDER_TO_OPENCV
    return Camera(w, h, fx, fy, cx, cy, c2w, params.name)


def world_to_camera_view(params: BlenderCameraParams, points: np.ndarray) -> np.ndarray:
    """NumPy twin of ``bpy_extras.object_utils.world_to_camera_view`` for ``[N,3]`` points.

    Returns ``[N,3]``: x, y normalised view coordinates ((0,0) bottom-left, (1,1) top-right
    of the frame) and z the depth along the view axis (negative behind the camera; a point
    at z = 0 gives (0.5, 0.5, 0) as in Blender). Computed from the camera frame the way
    ``Camera.view_frame(scene)`` builds it, independently of :func:`camera_from_blender`.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    m = np.linalg.inv(_normalized_matrix(params.matrix_world))
    co = pts @ m[:3, :3].T + m[:3, 3]
    z = -co[:, 2]
    # view frame (BKE_camera_view_frame_ex, drawsize 1, unit scale): aspect from resolution
    aspx = params.resolution_x * params.pixel_aspect_x
    aspy = params.resolution_y * params.pixel_aspect_y
    fit = (
        params.sensor_fit
        if params.sensor_fit != "AUTO"
        else ("HORIZONTAL" if aspx >= aspy else "VERTICAL")
    )
    r_asp = (1.0, aspy / aspx) if fit == "HORIZONTAL" else (aspx / aspy, 1.0)
    half_sensor = 0.5 * params.sensor_mm
    fac = 0.5
    depth = fac * params.lens_mm / half_sensor  # frame plane at local z = −depth
    sx, sy = params.shift_x * fac * 2.0, params.shift_y * fac * 2.0
    min_x, max_x = sx - fac * r_asp[0], sx + fac * r_asp[0]
    min_y, max_y = sy - fac * r_asp[1], sy + fac * r_asp[1]
    # perspective: the frame scaled to the point's depth (Blender: -(v / (v.z / z)))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = z / depth
        x = (co[:, 0] - min_x * s) / ((max_x - min_x) * s)
        y = (co[:, 1] - min_y * s) / ((max_y - min_y) * s)
    zero = z == 0.0
    x[zero], y[zero] = 0.5, 0.5
    return np.stack([x, y, z], -1)


def project_blender(
    params: BlenderCameraParams, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates ``[N,2]`` (engine convention: top-left origin, +0.5 centres) and
    planar depth ``[N]`` of world points, through Blender's ``world_to_camera_view``."""
    ndc = world_to_camera_view(params, points)
    w, h = params.render_size
    return np.stack([ndc[:, 0] * w, (1.0 - ndc[:, 1]) * h], -1), ndc[:, 2]


# ----------------------------------------------------------------------------- axes
#: Axis names of Blender's import/export orientation options.
AXES = ("X", "Y", "Z", "-X", "-Y", "-Z")
#: Forward axis that goes with each up axis when only the up is known (the smallest
#: rotation taking that up to Blender's +Z; −Y up gives COLMAP's convention, forward +Z).
FORWARD_FOR_UP = {"Z": "Y", "-Z": "-Y", "Y": "-Z", "-Y": "Z", "X": "Y", "-X": "Y"}


def axis_vector(name: str) -> np.ndarray:
    """Unit vector of an axis name (``'X'`` … ``'-Z'``)."""
    if name not in AXES:
        raise ValueError(f"axis must be one of {AXES}, got {name!r}")
    v = np.zeros(3)
    v["XYZ".index(name[-1])] = -1.0 if name.startswith("-") else 1.0
    return v


def axis_conversion(forward: str, up: str) -> np.ndarray:
    """``[3,3]`` rotation taking a file whose ``forward``/``up`` axes are given to
    Blender's (forward +Y, up +Z, right +X = forward × up) — what
    ``bpy_extras.io_utils.axis_conversion(from_forward=forward, from_up=up)`` returns.
    E.g. ``('Z', '-Y')``, COLMAP-trained 3DGS: x → x, y → −z, z → y."""
    f, u = axis_vector(forward), axis_vector(up)
    if abs(f @ u) > 0.5:
        raise ValueError(f"forward {forward!r} and up {up!r} must be different axes")
    return np.stack([np.cross(f, u), f, u])


def nearest_axis(v: np.ndarray) -> str:
    """The signed axis name closest to direction ``v``."""
    v = np.asarray(v, np.float64)
    k = int(np.argmax(np.abs(v)))
    return ("-" if v[k] < 0 else "") + "XYZ"[k]


def up_conversion(up: np.ndarray) -> np.ndarray:
    """``[3,3]`` rotation taking the scene direction ``up`` exactly to Blender's +Z: the
    axis conversion of the nearest axis (:data:`FORWARD_FOR_UP`), then the smallest
    rotation removing what tilt is left (none for an axis-aligned up)."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    ax = nearest_axis(u)
    m = axis_conversion(FORWARD_FOR_UP[ax], ax)
    a = m @ u
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(a, z)
    s, c = np.linalg.norm(axis), float(a @ z)
    if s < 1e-12:
        return m
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    tilt = np.eye(3) + s * kx + (1 - c) * (kx @ kx)  # Rodrigues, angle atan2(s, c)
    return tilt @ m


def conversion_matrix(rotation: np.ndarray) -> np.ndarray:
    """``[4,4]`` object matrix of a ``[3,3]`` conversion."""
    out = np.eye(4)
    out[:3, :3] = rotation
    return out

"""NeRF / instant-ngp / nerfstudio ``transforms.json`` reader and writer.

Layout: a JSON object with ``frames: [{file_path, transform_matrix, …}]``. Intrinsics may
sit at the top level or be overridden per frame (the frame's own keys win):

* focal: ``fl_x`` [``fl_y``] in pixels, else ``camera_angle_x`` [``camera_angle_y``] in
  radians (``f = 0.5 · size / tan(0.5 · angle)``); a missing y focal equals the x one.
* principal point ``cx, cy`` in pixels, default ``(w/2, h/2)``. instant-ngp and nerfstudio
  both cast rays through ``pixel + 0.5``, i.e. the engine's +0.5 convention: copied unchanged.
* image size ``w, h``; when absent it is read from the image header of ``file_path``
  (relative to the JSON's folder; NeRF-synthetic paths without extension try ``.png``,
  ``.jpg``, ``.jpeg``). PNG and JPEG headers are parsed directly (EXIF orientation is
  not applied, as in the trainers); other formats fall back to OpenCV.

``transform_matrix`` is the OpenGL camera-to-world (x right, y up, looking down −z):
``c2w_opencv = transform_matrix · diag(1, −1, −1, 1)``. Distortion keys (``k1…k4, p1, p2``)
are ignored with a warning; fisheye/equirectangular models are rejected. Camera names are
the frames' ``file_path`` strings, verbatim. Other keys (``aabb_scale``, ``scale``,
``offset``, ``applied_transform`` …) are not interpreted.
"""

from __future__ import annotations

import math
import struct
import warnings
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..output_paths import write_json_atomic
from .json_file import read_json

__all__ = ["OPENGL_TO_OPENCV", "image_size", "read_transforms_json", "write_transforms_json"]

#: right-multiply a c2w by this to swap between OpenGL and OpenCV camera axes (self-inverse).
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_PINHOLE_MODELS = {"OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"}
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")


# --- image size from the header --------------------------------------------------
def _png_size(head: bytes) -> tuple[int, int] | None:
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" and len(head) >= 24:
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    return None


def _jpeg_size(f) -> tuple[int, int] | None:
    """Walk JPEG marker segments up to the first SOF (start of frame) and read its size."""
    f.seek(2)
    while True:
        b = f.read(1)
        while b and b != b"\xff":  # resync on garbage
            b = f.read(1)
        while b == b"\xff":  # fill bytes
            b = f.read(1)
        if not b:
            return None
        m = b[0]
        if m in (0x01, 0xD8) or 0xD0 <= m <= 0xD7:  # markers without a payload
            continue
        if m in (0xD9, 0xDA):  # end of image / start of scan before any SOF
            return None
        seg = f.read(2)
        if len(seg) < 2:
            return None
        (n,) = struct.unpack(">H", seg)
        if m in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            body = f.read(5)
            if len(body) < 5:
                return None
            h, w = struct.unpack(">HH", body[1:5])
            return int(w), int(h)
        f.seek(n - 2, 1)


def image_size(path: str | PathLike) -> tuple[int, int] | None:
    """``(width, height)`` from the image header (PNG/JPEG) or OpenCV; None if unreadable."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            head = f.read(32)
            size = _png_size(head)
            if size is None and head[:2] == b"\xff\xd8":
                size = _jpeg_size(f)
    except OSError:
        return None
    if size is not None and size[0] > 0 and size[1] > 0:
        return size
    try:
        import cv2  # other formats (EXR, BMP, TIFF, WebP …): decode fully
    except ImportError:
        return None
    try:  # OpenCV refuses headers declaring more than its pixel limit with cv2.error
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return None
    return None if img is None else (int(img.shape[1]), int(img.shape[0]))


def _find_image(root: Path, file_path: str) -> Path | None:
    try:
        p = root / file_path
        if p.is_file():
            return p
        for ext in _IMAGE_SUFFIXES:
            q = p.with_name(p.name + ext)
            if q.is_file():
                return q
    except (OSError, ValueError):  # a name too long for the file system, a NUL byte, …
        return None
    return None


# --- reader -------------------------------------------------------------------------
def _num(frame: dict, top: dict, key: str) -> float | None:
    v = frame.get(key, top.get(key))
    return None if v is None else float(v)


def _frame_camera(path: Path, top: dict, fr: Any, i: int) -> tuple[Camera, bool]:
    if not isinstance(fr, dict):
        raise ValueError("frame is not a JSON object")
    if "transform_matrix" not in fr:
        raise KeyError("transform_matrix")
    model = fr.get("camera_model", top.get("camera_model"))
    if (model is not None and str(model).upper() not in _PINHOLE_MODELS) or fr.get(
        "is_fisheye", top.get("is_fisheye", False)
    ):
        raise ValueError(f"camera model {model or 'fisheye'!r} is not supported (pinhole only)")
    file_path = str(fr.get("file_path", ""))
    # image size: the frame's own, else the top level's, else the image header
    w, h = _num(fr, top, "w"), _num(fr, top, "h")
    if w is None or h is None:
        img = _find_image(path.parent, file_path) if file_path else None
        size = image_size(img) if img is not None else None
        if size is None:
            what = (
                f"image {file_path!r} was not found next to the file"
                if img is None
                else f"image {str(img)!r} could not be read"
            )
            raise ValueError(f"no 'w'/'h' given and the {what} to take its size from")
        w, h = float(size[0]), float(size[1])
    # focal: each key looked up frame-first; pixels win over angles; one axis may stand for both
    fx, fy = _num(fr, top, "fl_x"), _num(fr, top, "fl_y")
    ax, ay = _num(fr, top, "camera_angle_x"), _num(fr, top, "camera_angle_y")
    for name, a in (("camera_angle_x", ax), ("camera_angle_y", ay)):
        if a is not None and not 0.0 < a < math.pi:
            raise ValueError(f"{name}={a} must be a field of view in (0, pi) radians")
    if fx is None and ax is not None:
        fx = 0.5 * w / math.tan(0.5 * ax)
    if fy is None and ay is not None:
        fy = 0.5 * h / math.tan(0.5 * ay)
    if fx is None and fy is None:
        raise ValueError("no focal length: need 'fl_x' or 'camera_angle_x'")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    cx, cy = _num(fr, top, "cx"), _num(fr, top, "cy")
    m = np.asarray(fr["transform_matrix"], dtype=np.float64)
    if m.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"transform_matrix must be 4x4, got shape {m.shape}")
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    distorted = any(float(fr.get(k, top.get(k, 0.0)) or 0.0) != 0.0 for k in _DISTORTION_KEYS)
    wi, hi = int(round(w)), int(round(h))
    cam = Camera(
        wi,
        hi,
        fx,
        fy,
        wi / 2.0 if cx is None else cx,
        hi / 2.0 if cy is None else cy,
        m @ OPENGL_TO_OPENCV,
        file_path or f"frame_{i:05d}",
    )
    return cam, distorted


def read_transforms_json(path: str | PathLike, doc: Any = None) -> list[Camera]:
    """Engine cameras (OpenCV, +0.5 centres) of every frame, in file order."""
    path = Path(path)
    data = read_json(path, "camera file") if doc is None else doc  # doc: already parsed
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) or not data["frames"]:
        raise DivasInputError(
            path, "expected a JSON object with a non-empty 'frames' list (transforms.json)"
        )
    cams: list[Camera] = []
    distorted = 0
    for i, fr in enumerate(data["frames"]):
        try:
            cam, dist = _frame_camera(path, data, fr, i)
        except (KeyError, TypeError, ValueError, OverflowError) as err:
            what = f"missing key {err}" if isinstance(err, KeyError) else str(err)
            raise DivasInputError(path, f"frame {i}: {what}") from None
        cams.append(cam)
        distorted += dist
    if distorted:
        warnings.warn(
            f"{path}: lens distortion of {distorted} frame(s) is ignored; the cameras "
            f"are treated as pinhole. Undistort the images for accurate results.",
            UserWarning,
            stacklevel=2,
        )
    return cams


# --- writer -------------------------------------------------------------------------
def _intrinsics(c: Camera) -> dict[str, Any]:
    return {
        "camera_angle_x": c.fov_x,
        "camera_angle_y": c.fov_y,
        "fl_x": c.fx,
        "fl_y": c.fy,
        "cx": c.cx,
        "cy": c.cy,
        "w": c.width,
        "h": c.height,
    }


def write_transforms_json(path: str | PathLike, cameras: list[Camera]) -> None:
    """Write ``cameras`` as ``transforms.json`` (OpenGL ``transform_matrix``).

    Shared intrinsics go to the top level, otherwise per frame; ``file_path`` is the
    camera name (``frame_00000`` … when unnamed). ``camera_angle_x/y`` are written too,
    consistent with ``fl_x/fl_y``, for NeRF-synthetic style readers.
    """
    intr = [_intrinsics(c) for c in cameras]
    shared = bool(intr) and all(d == intr[0] for d in intr)
    out: dict[str, Any] = dict(intr[0]) if shared else {}
    frames = []
    for i, (c, d) in enumerate(zip(cameras, intr)):
        fr: dict[str, Any] = {
            "file_path": c.name or f"frame_{i:05d}",
            "transform_matrix": (c.c2w @ OPENGL_TO_OPENCV).tolist(),
        }
        if not shared:
            fr.update(d)
        frames.append(fr)
    out["frames"] = frames
    write_json_atomic(path, out)

"""The one camera type of the engine (NOTES "Conventions").

OpenCV convention: camera x right, y down, z forward. ``c2w`` maps camera to
world coordinates (4×4). Intrinsics are in pixels with pixel *centres* at +0.5:
pixel index ``(i, j)`` is the continuous point ``(i + 0.5, j + 0.5)`` and a camera
point ``(x, y, z)`` projects to ``(fx x/z + cx, fy y/z + cy)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Camera", "MAX_IMAGE_SIDE", "MAX_FOCAL", "MAX_PRINCIPAL"]

#: Largest accepted image side in pixels (16384 · 4): a camera file asking for more is
#: broken or hostile, and a render of it would not fit in memory anyway.
MAX_IMAGE_SIDE = 16384 * 4
#: Largest accepted focal length in pixels (a 0.0006° field of view at 1000 pixels).
MAX_FOCAL = 1e8
#: Largest accepted |principal point| in pixels (crops may move it far off the image).
MAX_PRINCIPAL = 1e8


def _image_side(name: str, k: str, v: Any, strict: bool = True) -> int:
    """``v`` as a whole number of pixels in ``1..MAX_IMAGE_SIDE``, else ``ValueError``
    (``strict=False``: a fractional value is truncated, as ``int`` does)."""
    try:
        f = float(v)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"camera {name!r}: {k}={v!r} is not a number") from None
    if not math.isfinite(f) or (strict and f != int(f)):
        raise ValueError(f"camera {name!r}: {k}={v!r} is not a whole number of pixels")
    if not 1 <= f <= MAX_IMAGE_SIDE:
        raise ValueError(f"camera {name!r}: {k}={int(f)} is outside 1..{MAX_IMAGE_SIDE} pixels")
    return int(f)


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera.

    Attributes:
        width, height: image size in pixels.
        fx, fy, cx, cy: intrinsics in pixels (principal point in the +0.5 convention).
        c2w: ``[4,4]`` float64 camera-to-world transform (OpenCV axes).
        name: optional identifier (training image name, anchor id, …).
        near: this camera's own near clip distance, planar depth in world units (like a
            Blender camera's ``clip_start``); renderers clip at ``max(their near, near)``
            (:meth:`clip_near`). 0 (default): the renderer's near alone. Views the engine
            synthesises around a target (centroid views) set it to a fraction of their
            orbit radius, so a camera placed next to a faint floater does not see it.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    c2w: np.ndarray = field(default_factory=lambda: np.eye(4))
    name: str = ""
    near: float = 0.0

    def __post_init__(self) -> None:
        c2w = np.asarray(self.c2w, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0, 0, 0, 1]])
        if c2w.shape != (4, 4):
            raise ValueError(f"camera {self.name!r}: c2w must be 4x4, got shape {c2w.shape}")
        if not np.all(np.isfinite(c2w)):
            raise ValueError(f"camera {self.name!r}: c2w contains NaN/Inf")
        r = c2w[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
            raise ValueError(f"camera {self.name!r}: c2w rotation is not a proper rotation")
        for k in ("fx", "fy", "cx", "cy"):
            try:
                float(getattr(self, k))
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"camera {self.name!r}: {k} is not a number") from None
        for k in ("fx", "fy"):
            v = float(getattr(self, k))
            if not math.isfinite(v) or v <= 0 or v > MAX_FOCAL:
                raise ValueError(
                    f"camera {self.name!r}: focal length {k}={v} must be positive "
                    f"and ≤ {MAX_FOCAL:g}"
                )
        for k in ("cx", "cy"):
            v = float(getattr(self, k))
            if not math.isfinite(v) or abs(v) > MAX_PRINCIPAL:
                raise ValueError(
                    f"camera {self.name!r}: principal point {k}={v} must be finite, |{k}| ≤ "
                    f"{MAX_PRINCIPAL:g}"
                )
        near = float(self.near)
        if not math.isfinite(near) or near < 0:
            raise ValueError(f"camera {self.name!r}: near clip {self.near} must be finite and ≥ 0")
        object.__setattr__(self, "near", near)
        try:
            empty = int(self.width) <= 0 or int(self.height) <= 0
        except (TypeError, ValueError, OverflowError):
            empty = False  # reported by _image_side below
        if empty:
            raise ValueError(
                f"camera {self.name!r}: image size {self.width}x{self.height} is empty"
            )
        object.__setattr__(self, "c2w", c2w)
        object.__setattr__(self, "width", _image_side(self.name, "width", self.width, False))
        object.__setattr__(self, "height", _image_side(self.name, "height", self.height, False))
        for k in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, k, float(getattr(self, k)))

    # --- pose -------------------------------------------------------------
    @property
    def w2c(self) -> np.ndarray:
        r, t = self.c2w[:3, :3], self.c2w[:3, 3]
        out = np.eye(4)
        out[:3, :3] = r.T
        out[:3, 3] = -r.T @ t
        return out

    @property
    def center(self) -> np.ndarray:
        return self.c2w[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """World direction of the optical axis (+z of the camera)."""
        return self.c2w[:3, 2].copy()

    @property
    def up(self) -> np.ndarray:
        """World up of the image (−y of the OpenCV camera)."""
        return -self.c2w[:3, 1]

    @property
    def right(self) -> np.ndarray:
        return self.c2w[:3, 0].copy()

    # --- intrinsics -------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def fov_x(self) -> float:
        return 2.0 * math.atan(self.width / (2.0 * self.fx))

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    def scaled(self, s: float) -> Camera:
        """Same pose, image resized by ``s`` (intrinsics scale exactly with +0.5 centres)."""
        w, h = max(1, round(self.width * s)), max(1, round(self.height * s))
        sx, sy = w / self.width, h / self.height
        return Camera(
            w,
            h,
            self.fx * sx,
            self.fy * sy,
            self.cx * sx,
            self.cy * sy,
            self.c2w,
            self.name,
            self.near,
        )

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Camera:
        """Same pose and focal, image cut to the pixel window ``[x0, x0+width) ×
        [y0, y0+height)`` of this camera's image: pixel ``(i, j)`` of the crop is pixel
        ``(i + x0, j + y0)`` here (the principal point moves by ``-(x0, y0)``). A render
        of the crop equals that window of the full render, at the cost of the window."""
        x0, y0 = int(x0), int(y0)
        if not (0 <= x0 < self.width and 0 <= y0 < self.height):
            raise ValueError(f"camera {self.name!r}: crop origin ({x0}, {y0}) is off the image")
        width = min(int(width), self.width - x0)
        height = min(int(height), self.height - y0)
        return Camera(
            width,
            height,
            self.fx,
            self.fy,
            self.cx - x0,
            self.cy - y0,
            self.c2w,
            self.name,
            self.near,
        )

    def pixels_to(self, other: Camera, xy) -> np.ndarray:
        """Pixels ``xy [..., 2]`` of this camera's image in ``other``'s image of the same
        view (``other`` is this camera resized, e.g. the full camera's render at a scale,
        :meth:`scaled`): ``(x·w'/w, y·h'/h)``, exact with pixel centres at +0.5."""
        sx, sy = other.width / self.width, other.height / self.height
        return np.asarray(xy, np.float64) * (sx, sy)

    def with_pose(self, c2w: np.ndarray, name: str | None = None) -> Camera:
        return Camera(
            self.width,
            self.height,
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            c2w,
            self.name if name is None else name,
            self.near,
        )

    def with_near(self, near: float) -> Camera:
        """Same camera with its own near clip distance set to ``near``."""
        return Camera(
            self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.c2w, self.name, near
        )

    def clip_near(self, renderer_near: float) -> float:
        """The near plane a renderer with near ``renderer_near`` uses for this camera."""
        return max(float(renderer_near), self.near)

    # --- projection -------------------------------------------------------
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """``[N,3]`` camera-space coordinates of world points."""
        w2c = self.w2c
        return np.asarray(points, dtype=np.float64) @ w2c[:3, :3].T + w2c[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``[N,2]`` (continuous, +0.5 centres) and planar depth ``[N]``."""
        pc = self.world_to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], -1)
        return uv, z

    def in_image(self, uv: np.ndarray, z: np.ndarray, near: float = 0.0) -> np.ndarray:
        """``[N]`` bool: projected points (:meth:`project`) in front of ``near`` whose
        finite pixel coordinates fall inside the image."""
        with np.errstate(invalid="ignore"):
            return (
                (z > near)
                & np.isfinite(uv).all(axis=1)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] < self.width)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < self.height)
            )

    def ray_directions(self, uv: np.ndarray) -> np.ndarray:
        """Unit world-space ray directions ``[N,3]`` through continuous pixel points ``uv``."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        d = np.stack(
            [(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy, np.ones(len(uv))], -1
        )
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d @ self.c2w[:3, :3].T

    def unproject(self, uv: np.ndarray, planar_depth: np.ndarray) -> np.ndarray:
        """World points ``[N,3]`` at planar depth ``z`` behind continuous pixel points."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(planar_depth, dtype=np.float64).reshape(-1)
        pc = np.stack(
            [(uv[:, 0] - self.cx) / self.fx * z, (uv[:, 1] - self.cy) / self.fy * z, z], -1
        )
        return pc @ self.c2w[:3, :3].T + self.c2w[:3, 3]

    # --- construction -----------------------------------------------------
    @classmethod
    def look_at(
        cls,
        eye: np.ndarray,
        target: np.ndarray,
        up: np.ndarray,
        *,
        width: int,
        height: int,
        fx: float,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        name: str = "",
        near: float = 0.0,
    ) -> Camera:
        """A camera at ``eye`` looking at ``target`` with image-up close to ``up``."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        fwd = target - eye
        n = np.linalg.norm(fwd)
        if n == 0:
            raise ValueError("look_at: eye and target coincide")
        fwd /= n
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-8:  # up parallel to the view: pick any perpendicular
            helper = np.array([1.0, 0, 0]) if abs(fwd[0]) < 0.9 else np.array([0, 1.0, 0])
            right = np.cross(fwd, helper)
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
        return cls(
            width,
            height,
            fx,
            fy if fy is not None else fx,
            width / 2.0 if cx is None else cx,
            height / 2.0 if cy is None else cy,
            c2w,
            name,
            near,
        )

    # --- (de)serialisation in the NOTES prompts-file camera schema ----------
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "c2w": self.c2w.tolist(),
        }
        if self.name:
            d["name"] = self.name
        if self.near > 0:
            d["near"] = self.near
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        """Inverse of :meth:`to_dict`; raises ``ValueError``/``KeyError`` on a bad entry.
        ``name`` and ``near`` are optional."""
        known = {"width", "height", "fx", "fy", "cx", "cy", "c2w", "name", "near"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown camera keys {sorted(unknown)}")
        missing = known - {"name", "near"} - set(d)
        if missing:
            raise ValueError(f"camera is missing {sorted(missing)}")
        try:
            c2w = np.asarray(d["c2w"], dtype=np.float64)
            vals = [float(d[k]) for k in ("fx", "fy", "cx", "cy")]
            near = float(d.get("near", 0.0))
        except (TypeError, ValueError, OverflowError) as e:
            raise ValueError(f"camera has a non-numeric entry ({e})") from None
        name = d.get("name", "")
        if not isinstance(name, str):
            raise ValueError(f"camera name must be a string, got {type(name).__name__}")
        w = _image_side(name, "width", d["width"])
        h = _image_side(name, "height", d["height"])
        return cls(w, h, *vals, c2w, name, near)

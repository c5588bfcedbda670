"""COLMAP sparse model (``cameras.bin|txt`` + ``images.bin|txt``) reader and writer.

Format (COLMAP "Output Format" docs), binary little endian: ``cameras.bin`` — ``uint64 n``, per
camera ``uint32 camera_id, int32 model_id, uint64 width, height, float64 params[k]``;
``images.bin`` — ``uint64 n``, per image ``uint32 image_id, float64 qw qx qy qz, tx ty tz,
uint32 camera_id, char name[]`` (NUL-terminated), then its 2D points. Text files hold the same
fields (``#`` comments; the 2D-point line of ``images.txt`` is ignored).

Pose: ``(q, t)`` is world-to-camera with camera axes x right, y down, z forward — the engine's
OpenCV convention, so ``c2w = [Rᵀ | −Rᵀ t]`` and no flip. COLMAP's pixel centres are at +0.5
like the engine's, so ``cx, cy`` are copied unchanged.

Camera models: ``SIMPLE_PINHOLE``, ``PINHOLE``; ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` are
read with their distortion ignored (a ``UserWarning`` lists the distorted cameras); any other
model is a :class:`~divas_engine.errors.DivasInputError`. ``points3D`` is not read. Cameras are
returned sorted by image name (the order the 3DGS trainers use).
"""

from __future__ import annotations

import math
import struct
import warnings
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..output_paths import write_bytes_atomic, write_text_atomic

__all__ = [
    "CAMERA_MODELS",
    "ColmapCamera",
    "ColmapImage",
    "find_colmap_model",
    "qvec_to_rotmat",
    "read_colmap",
    "read_colmap_model",
    "rotmat_to_qvec",
    "write_colmap",
]

#: model name -> (model id, number of params), as in COLMAP's ``models.h``.
CAMERA_MODELS: dict[str, tuple[int, int]] = {
    "SIMPLE_PINHOLE": (0, 3),
    "PINHOLE": (1, 4),
    "SIMPLE_RADIAL": (2, 4),
    "RADIAL": (3, 5),
    "OPENCV": (4, 8),
    "OPENCV_FISHEYE": (5, 8),
    "FULL_OPENCV": (6, 12),
    "FOV": (7, 5),
    "SIMPLE_RADIAL_FISHEYE": (8, 4),
    "RADIAL_FISHEYE": (9, 5),
    "THIN_PRISM_FISHEYE": (10, 12),
    "RAD_TAN_THIN_PRISM_FISHEYE": (11, 16),
}
_MODEL_BY_ID = {mid: (name, n) for name, (mid, n) in CAMERA_MODELS.items()}
#: supported models: name -> (indices of fx, fy, cx, cy in params, first distortion index)
_SUPPORTED: dict[str, tuple[tuple[int, int, int, int], int]] = {
    "SIMPLE_PINHOLE": ((0, 0, 1, 2), 3),
    "PINHOLE": ((0, 1, 2, 3), 4),
    "SIMPLE_RADIAL": ((0, 0, 1, 2), 3),
    "RADIAL": ((0, 0, 1, 2), 3),
    "OPENCV": ((0, 1, 2, 3), 4),
}


@dataclass(frozen=True)
class ColmapCamera:
    """One COLMAP camera (intrinsics shared by images). ``params`` in COLMAP's order."""

    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    """One registered image: world-to-camera ``qvec`` (w, x, y, z) ``[4]`` and ``tvec`` ``[3]``."""

    image_id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str


# --- rotations ---------------------------------------------------------------
def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """``[3,3]`` rotation of the unit quaternion ``(w, x, y, z)`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotmat_to_qvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w ≥ 0``, of a ``[3,3]`` rotation (Shepperd)."""
    r = np.asarray(r, dtype=np.float64)
    tr = np.trace(r)
    k = int(np.argmax([tr, r[0, 0], r[1, 1], r[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


# --- locating a model ----------------------------------------------------------
def _model_files(d: Path) -> tuple[Path, Path] | None:
    for ext in (".bin", ".txt"):  # COLMAP prefers binary when both exist
        c, i = d / f"cameras{ext}", d / f"images{ext}"
        if c.is_file() and i.is_file():
            return c, i
    return None


def find_colmap_model(path: str | PathLike) -> Path | None:
    """The COLMAP model folder at or below ``path`` (itself, ``sparse/0``, ``sparse``), or None.

    ``path`` may also be one of the model's ``cameras.*``/``images.*`` files.
    """
    p = Path(path)
    if p.is_file() and p.stem in ("cameras", "images") and p.suffix in (".bin", ".txt"):
        p = p.parent
    if not p.is_dir():
        return None
    for d in (p, p / "sparse" / "0", p / "sparse"):
        if d.is_dir() and _model_files(d):
            return d
    return None


# --- binary parsing ------------------------------------------------------------
class _Buf:
    """Bounds-checked little-endian reader that names the file when it runs out."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise DivasInputError(path, f"cannot read COLMAP file ({e})") from None
        self.pos = 0

    def take(self, fmt: str, what: str) -> tuple:
        n = struct.calcsize(fmt)
        if self.pos + n > len(self.data):
            raise DivasInputError(
                self.path,
                f"truncated binary file: {what} needs {n} bytes at "
                f"offset {self.pos}, file has {len(self.data)}",
            )
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += n
        return out

    def skip(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > len(self.data):
            raise DivasInputError(
                self.path,
                f"truncated binary file: {what} needs {n} bytes at "
                f"offset {self.pos}, file has {len(self.data)}",
            )
        self.pos += n

    def cstring(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise DivasInputError(
                self.path, f"truncated binary file: {what} has no terminating NUL"
            )
        raw = self.data[self.pos : end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            return raw.decode("latin-1")

    def count(self, min_record: int, what: str) -> int:
        (n,) = self.take("<Q", f"number of {what}")
        if n * min_record > len(self.data) - self.pos:
            left = len(self.data) - self.pos
            raise DivasInputError(
                self.path,
                f"truncated or corrupt binary file: header says "
                f"{n} {what}, but only {left} bytes follow",
            )
        return n

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise DivasInputError(
                self.path,
                f"corrupt binary file: {len(self.data) - self.pos} "
                f"unexpected trailing bytes at offset {self.pos}",
            )


def _read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    b = _Buf(path)
    out: dict[int, ColmapCamera] = {}
    for i in range(b.count(24, "cameras")):
        cam_id, model_id, w, h = b.take("<IiQQ", f"camera record {i}")
        if model_id not in _MODEL_BY_ID:
            raise DivasInputError(
                path, f"camera {cam_id}: unknown COLMAP camera model id {model_id}"
            )
        model, n = _MODEL_BY_ID[model_id]
        params = b.take(f"<{n}d", f"camera {cam_id} parameters")
        if cam_id in out:
            raise DivasInputError(path, f"camera id {cam_id} is defined twice")
        out[cam_id] = ColmapCamera(cam_id, model, int(w), int(h), tuple(params))
    b.finish()
    return out


def _read_images_bin(path: Path) -> list[ColmapImage]:
    b = _Buf(path)
    out: list[ColmapImage] = []
    for i in range(b.count(73, "images")):
        rec = b.take("<I7dI", f"image record {i}")
        name = b.cstring(f"image {rec[0]} name")
        (npts,) = b.take("<Q", f"image {rec[0]} number of 2D points")
        b.skip(24 * npts, f"image {rec[0]} 2D points")
        out.append(ColmapImage(rec[0], np.array(rec[1:5]), np.array(rec[5:8]), rec[8], name))
    b.finish()
    return out


# --- text parsing --------------------------------------------------------------
def _read_text(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as e:
        raise DivasInputError(path, f"cannot read COLMAP file ({e})") from None


def _read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    out: dict[int, ColmapCamera] = {}
    for ln, line in enumerate(_read_text(path), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        e = s.split()
        try:
            cam_id, model, w, h = int(e[0]), e[1], int(e[2]), int(e[3])
            params = tuple(float(v) for v in e[4:])
        except (IndexError, ValueError):
            raise DivasInputError(
                path, f"line {ln}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS…', got {s[:80]!r}"
            ) from None
        if model not in CAMERA_MODELS:
            raise DivasInputError(path, f"line {ln}: unknown COLMAP camera model {model!r}")
        if len(params) != CAMERA_MODELS[model][1]:
            raise DivasInputError(
                path,
                f"line {ln}: camera model {model} takes "
                f"{CAMERA_MODELS[model][1]} parameters, got {len(params)}",
            )
        if cam_id in out:
            raise DivasInputError(path, f"line {ln}: camera id {cam_id} is defined twice")
        out[cam_id] = ColmapCamera(cam_id, model, w, h, params)
    return out


def _is_points_line(line: str) -> bool:
    """True for a POINTS2D line: empty, or all-numeric ``X Y POINT3D_ID`` triples."""
    e = line.split()
    if len(e) % 3:
        return False
    try:
        [float(v) for v in e]
    except ValueError:
        return False
    return True


def _read_images_txt(path: Path) -> list[ColmapImage]:
    lines = _read_text(path)
    out: list[ColmapImage] = []
    k = 0
    while k < len(lines):
        s = lines[k].strip()
        k += 1
        if not s or s.startswith("#"):
            continue
        e = s.split()
        try:
            if len(e) < 10:
                raise ValueError
            img_id = int(e[0])
            vals = [float(v) for v in e[1:8]]
            cam_id = int(e[8])
        except ValueError:
            raise DivasInputError(
                path,
                f"line {k}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ "
                f"CAMERA_ID NAME', got {s[:80]!r}",
            ) from None
        out.append(
            ColmapImage(img_id, np.array(vals[:4]), np.array(vals[4:]), cam_id, " ".join(e[9:]))
        )
        if k < len(lines) and _is_points_line(lines[k]):
            k += 1  # the POINTS2D line that follows every image line (may be empty)
    return out


# --- public API ----------------------------------------------------------------
def read_colmap_model(
    path: str | PathLike,
) -> tuple[dict[int, ColmapCamera], list[ColmapImage], tuple[Path, Path]]:
    """Raw COLMAP cameras (by id), images and the two files read.

    ``path``: a model folder, a scene folder with ``sparse/0`` or ``sparse``, or one model file.
    """
    d = find_colmap_model(path)
    if d is None:
        raise DivasInputError(
            path,
            "no COLMAP model found (expected cameras.bin + images.bin or "
            "cameras.txt + images.txt here, in sparse/0 or in sparse)",
        )
    cpath, ipath = _model_files(d)  # type: ignore[misc]
    if cpath.suffix == ".bin":
        return _read_cameras_bin(cpath), _read_images_bin(ipath), (cpath, ipath)
    return _read_cameras_txt(cpath), _read_images_txt(ipath), (cpath, ipath)


def read_colmap(path: str | PathLike) -> list[Camera]:
    """Engine cameras (OpenCV, +0.5 pixel centres) of every registered image, sorted by name."""
    cams, images, (cpath, ipath) = read_colmap_model(path)
    if not images:
        raise DivasInputError(ipath, "COLMAP model has no registered images")
    distorted: list[str] = []
    out: list[Camera] = []
    for im in images:
        if im.camera_id not in cams:
            raise DivasInputError(
                ipath,
                f"image {im.image_id} ({im.name!r}) refers to camera "
                f"{im.camera_id}, which {cpath.name} does not define "
                f"(cameras: {sorted(cams)[:10]})",
            )
        c = cams[im.camera_id]
        if c.model not in _SUPPORTED:
            raise DivasInputError(
                cpath,
                f"camera {c.camera_id}: COLMAP model {c.model} is not "
                f"supported (use PINHOLE/SIMPLE_PINHOLE; undistort the "
                f"images first, e.g. `colmap image_undistorter`)",
            )
        (ifx, ify, icx, icy), d0 = _SUPPORTED[c.model]
        if any(v != 0.0 for v in c.params[d0:]):
            distorted.append(f"{c.camera_id} ({c.model})")
        qn = float(np.linalg.norm(im.qvec))
        if not math.isfinite(qn) or qn < 1e-12:
            raise DivasInputError(
                ipath,
                f"image {im.image_id} ({im.name!r}): invalid rotation "
                f"quaternion {im.qvec.tolist()}",
            )
        r = qvec_to_rotmat(im.qvec)
        c2w = np.eye(4)
        c2w[:3, :3] = r.T
        c2w[:3, 3] = -r.T @ im.tvec
        p = c.params
        try:
            out.append(Camera(c.width, c.height, p[ifx], p[ify], p[icx], p[icy], c2w, im.name))
        except ValueError as e:
            raise DivasInputError(cpath, f"camera {c.camera_id} (image {im.name!r}): {e}") from None
    if distorted:
        warnings.warn(
            f"{cpath}: lens distortion of camera(s) {', '.join(sorted(set(distorted)))} "
            f"is ignored; the cameras are treated as pinhole. Undistort the images "
            f"(e.g. `colmap image_undistorter`) for accurate results.",
            UserWarning,
            stacklevel=2,
        )
    out.sort(key=lambda cam: cam.name)
    return out


def _check_name(name: str) -> str:
    if not name or any(ch in name for ch in "\0\n\r"):
        raise ValueError(f"image name {name!r} cannot be stored in a COLMAP model")
    return name


def write_colmap(path: str | PathLike, cameras: list[Camera], binary: bool = True) -> Path:
    """Write ``cameras`` as a COLMAP model folder (``cameras``, ``images``, empty ``points3D``).

    PINHOLE cameras; identical intrinsics share one camera id. Unnamed cameras become
    ``image_00000`` … Returns the folder. Existing files of the same names are replaced.
    """
    d = Path(path)
    d.mkdir(parents=True, exist_ok=True)
    if not binary and (d / "cameras.bin").exists():
        warnings.warn(
            f"{d}: cameras.bin exists next to the text model being written; COLMAP "
            f"and this reader prefer the binary files",
            UserWarning,
            stacklevel=2,
        )
    intr: dict[tuple, int] = {}
    cam_rows: list[tuple[int, int, int, tuple[float, ...]]] = []
    img_rows: list[tuple[int, np.ndarray, np.ndarray, int, str]] = []
    for i, c in enumerate(cameras):
        key = (c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        if key not in intr:
            intr[key] = len(intr) + 1
            cam_rows.append((intr[key], c.width, c.height, (c.fx, c.fy, c.cx, c.cy)))
        w2c = c.w2c
        img_rows.append(
            (
                i + 1,
                rotmat_to_qvec(w2c[:3, :3]),
                w2c[:3, 3],
                intr[key],
                _check_name(c.name or f"image_{i:05d}"),
            )
        )
    pin_id = CAMERA_MODELS["PINHOLE"][0]
    if binary:
        cb = [struct.pack("<Q", len(cam_rows))]
        for cid, w, h, p in cam_rows:
            cb.append(struct.pack("<IiQQ4d", cid, pin_id, w, h, *p))
        ib = [struct.pack("<Q", len(img_rows))]
        for iid, q, t, cid, name in img_rows:
            ib.append(
                struct.pack("<I7dI", iid, *q, *t, cid)
                + name.encode("utf-8")
                + b"\0"
                + struct.pack("<Q", 0)
            )
        write_bytes_atomic(d / "cameras.bin", b"".join(cb))
        write_bytes_atomic(d / "images.bin", b"".join(ib))
        write_bytes_atomic(d / "points3D.bin", struct.pack("<Q", 0))
    else:
        g = lambda v: format(float(v), ".17g")  # noqa: E731  (exact float round trip)
        ct = [
            "# Camera list with one line of data per camera:",
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"# Number of cameras: {len(cam_rows)}",
        ]
        ct += [f"{cid} PINHOLE {w} {h} " + " ".join(g(v) for v in p) for cid, w, h, p in cam_rows]
        it = [
            "# Image list with two lines of data per image:",
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
            "#   POINTS2D[] as (X, Y, POINT3D_ID)",
            f"# Number of images: {len(img_rows)}, mean observations per image: 0",
        ]
        for iid, q, t, cid, name in img_rows:
            it.append(f"{iid} " + " ".join(g(v) for v in (*q, *t)) + f" {cid} {name}")
            it.append("")
        write_text_atomic(d / "cameras.txt", "\n".join(ct) + "\n")
        write_text_atomic(d / "images.txt", "\n".join(it) + "\n")
        write_text_atomic(
            d / "points3D.txt",
            "# 3D point list with one line of data per point:\n"
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]\n"
            "# Number of points: 0, mean track length: 0\n",
        )
    return d

"""Camera files of any supported kind: detection, loading and saving.

Detection (:func:`detect_camera_format`):

* a ``.json`` file holding a list → 3DGS/2DGS ``cameras.json``;
  an object with ``frames`` → NeRF/instant-ngp ``transforms.json``;
* a folder holding ``cameras.bin|txt`` + ``images.bin|txt``, or such a model in
  ``sparse/0`` or ``sparse`` below it, or one of those model files → COLMAP;
* a folder with none of these but a ``transforms.json`` or ``cameras.json`` → that file
  (in this order; COLMAP wins when both kinds are present);
* anything else → :class:`~divas_engine.errors.DivasInputError`.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from ..camera import Camera
from ..errors import DivasInputError
from .cameras_json import read_cameras_json, write_cameras_json
from .colmap import find_colmap_model, read_colmap, write_colmap
from .json_file import read_json
from .limits import input_guard
from .transforms_json import read_transforms_json, write_transforms_json

__all__ = ["CAMERA_FORMATS", "detect_camera_format", "load_cameras", "save_cameras"]

#: format names accepted by :func:`save_cameras` and returned by :func:`detect_camera_format`.
CAMERA_FORMATS = ("cameras_json", "transforms_json", "colmap", "colmap_text")


def _json_at(path: Path) -> tuple[str, Path, object]:
    """The JSON camera format of ``path``, the path and the parsed document (parsed once)."""
    data = read_json(path, "camera file")
    if isinstance(data, list):
        return "cameras_json", path, data
    if isinstance(data, dict) and "frames" in data:
        return "transforms_json", path, data
    raise DivasInputError(
        path,
        "unknown camera format: JSON is neither a list of cameras "
        "(3DGS cameras.json) nor an object with 'frames' (transforms.json)",
    )


def detect_camera_format(path: str | PathLike) -> tuple[str, Path]:
    """``(format, path to read)`` for a camera file or folder; format in :data:`CAMERA_FORMATS`."""
    fmt, p, _ = _detect(path)
    return fmt, p


def _detect(path: str | PathLike) -> tuple[str, Path, object]:
    """:func:`detect_camera_format` plus the parsed JSON document (None for COLMAP)."""
    p = Path(path)
    if not p.exists():
        raise DivasInputError(p, "camera file or folder does not exist")
    model = find_colmap_model(p)
    if model is not None:
        return "colmap", model, None
    if p.is_file():
        if p.suffix.lower() == ".json":
            return _json_at(p)
    elif p.is_dir():
        for name in ("transforms.json", "cameras.json"):
            if (p / name).is_file():
                return _json_at(p / name)
    raise DivasInputError(
        p,
        "unknown camera format (expected a 3DGS cameras.json, a "
        "transforms.json, or a COLMAP model folder with cameras.bin|txt + "
        "images.bin|txt, possibly in sparse/0)",
    )


def load_cameras(path: str | PathLike) -> list[Camera]:
    """Cameras (engine convention) from any supported camera file or folder."""
    with input_guard(path, "camera file"):
        fmt, p, doc = _detect(path)
        if fmt == "colmap":
            return read_colmap(p)
        if fmt == "transforms_json":
            return read_transforms_json(p, doc)
        return read_cameras_json(p, doc)


def save_cameras(path: str | PathLike, cameras: list[Camera], fmt: str | None = None) -> Path:
    """Write ``cameras``; returns what was written (a file or a COLMAP folder).

    ``fmt`` (one of :data:`CAMERA_FORMATS`) defaults from the path: ``*.json`` whose name
    contains ``transforms`` → transforms.json, any other ``*.json`` → 3DGS cameras.json,
    an existing folder or a path without suffix → binary COLMAP model folder.
    """
    p = Path(path)
    if fmt is None:
        if p.suffix.lower() == ".json":
            fmt = "transforms_json" if "transforms" in p.name.lower() else "cameras_json"
        elif p.suffix == "" or p.is_dir():
            fmt = "colmap"
        else:
            raise DivasInputError(
                p,
                "cannot choose a camera format from this path: use a .json "
                "file name or a folder (COLMAP), or pass fmt=",
            )
    if fmt not in CAMERA_FORMATS:
        raise ValueError(f"unknown camera format {fmt!r}; choose one of {CAMERA_FORMATS}")
    if not cameras:
        raise ValueError("no cameras to save")
    if fmt in ("colmap", "colmap_text"):
        return write_colmap(p, cameras, binary=(fmt == "colmap"))
    p.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "transforms_json":
        write_transforms_json(p, cameras)
    else:
        write_cameras_json(p, cameras)
    return p

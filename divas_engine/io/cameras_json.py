"""3DGS/2DGS ``cameras.json`` (written by the reference trainers).

Each entry: ``id, img_name, width, height, position[3], rotation[3][3], fx, fy``.
``rotation`` is the camera-to-world rotation and ``position`` the camera centre,
both in the OpenCV convention (NOTES "Conventions"). Principal point is not
stored by the trainers: it is the image centre unless ``cx``/``cy`` are present
(the synthetic scenes write them).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..output_paths import write_json_atomic
from .json_file import read_json

__all__ = ["read_cameras_json", "write_cameras_json"]


def read_cameras_json(path: str | PathLike, doc: Any = None) -> list[Camera]:
    path = Path(path)
    data = read_json(path, "camera file") if doc is None else doc  # doc: already parsed
    if not isinstance(data, list) or not data:
        raise DivasInputError(path, "expected a non-empty JSON list of cameras (3DGS cameras.json)")
    cams = []
    for i, e in enumerate(data):
        try:
            c2w = np.eye(4)
            c2w[:3, :3] = np.asarray(e["rotation"], dtype=np.float64)
            c2w[:3, 3] = np.asarray(e["position"], dtype=np.float64)
            w, h = int(e["width"]), int(e["height"])
            cams.append(
                Camera(
                    w,
                    h,
                    float(e["fx"]),
                    float(e["fy"]),
                    float(e.get("cx", w / 2.0)),
                    float(e.get("cy", h / 2.0)),
                    c2w,
                    str(e.get("img_name", e.get("id", i))),
                )
            )
        except (KeyError, TypeError, ValueError, OverflowError) as err:
            what = f"missing key {err}" if isinstance(err, KeyError) else str(err)
            raise DivasInputError(path, f"camera entry {i}: {what}") from None
    return cams


def write_cameras_json(path: str | PathLike, cameras: list[Camera]) -> None:
    """Write cameras in the 3DGS schema (plus ``cx``/``cy`` so no intrinsic is lost)."""
    out = []
    for i, c in enumerate(cameras):
        out.append(
            {
                "id": i,
                "img_name": c.name or f"{i:05d}",
                "width": c.width,
                "height": c.height,
                "position": c.c2w[:3, 3].tolist(),
                "rotation": c.c2w[:3, :3].tolist(),
                "fx": c.fx,
                "fy": c.fy,
                "cx": c.cx,
                "cy": c.cy,
            }
        )
    write_json_atomic(path, out)

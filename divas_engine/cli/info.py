"""``divas info PATH [--cameras C] [--json]``: what is in a scene file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info", help="describe a scene file (counts, bounds, robust centre, SH, scales)"
    )
    p.add_argument(
        "path",
        type=Path,
        help="scene: .ply (2DGS/3DGS/compressed), .splat, .spz, SOG (.sog, folder or its "
        "meta.json) or .npz grid",
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="camera file/folder (default: cameras.json beside the scene, if any)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _cameras_info(path: Path) -> dict:
    from ..io.cameras import load_cameras

    cams = load_cameras(path)
    sizes = sorted({(c.width, c.height) for c in cams})
    return {
        "cameras_file": str(path),
        "camera_count": len(cams),
        "image_sizes": [list(s) for s in sizes],
    }


def run(args: argparse.Namespace) -> int:
    from ..io.load import load_scene
    from ..scene_stats import scene_summary

    scene = load_scene(args.path)
    info = scene_summary(scene)
    cams = args.cameras
    if cams is None and (args.path.parent / "cameras.json").is_file():
        cams = args.path.parent / "cameras.json"
    if cams is not None:
        info.update(_cameras_info(cams))
    else:
        info["camera_count"] = 0
    if args.json:
        print(json.dumps(info))
        return 0
    for k, v in info.items():
        if isinstance(v, dict):
            v = "  ".join(f"{kk}={vv:.4g}" for kk, vv in v.items())
        elif isinstance(v, list) and v and isinstance(v[0], float):
            v = "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
        elif isinstance(v, float):
            v = f"{v:.6g}"
        print(f"{k:>18}: {v}")
    return 0


__all__ = ["add_parser", "run"]

"""``divas info PATH [--cameras C] [--up X,Y,Z] [--json]``: what is in a scene file.

Besides counts and statistics it reports the scene up and where it came from
(``up``, ``up_source``, ``up_confidence``, ``up_reason``): the training cameras when
there are any, else a ground plane of the scene or the capture convention
(:func:`~divas_engine.views.estimate_scene_up`), or ``--up``.
"""

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
        "meta.json), streamed LOD (lod-meta.json) or .npz grid",
    )
    p.add_argument(
        "--lod",
        type=int,
        default=None,
        metavar="N",
        help="streamed LOD scenes: the level to describe (default 0, the finest)",
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="camera file/folder (default: cameras.json beside the scene, if any)",
    )
    p.add_argument(
        "--up",
        default=None,
        metavar="X,Y,Z",
        help="scene up to report instead of the estimate (as `divas anchors --up`)",
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


def _up_info(scene, cameras_path: Path | None, up, frame) -> dict:
    """``up``, ``up_source``, ``up_confidence`` (None with cameras), ``up_reason``."""
    import numpy as np

    from ..io.cameras import load_cameras
    from ..views import estimate_scene_up, estimate_up, scene_points

    if cameras_path is not None and up is None:
        est = estimate_up(load_cameras(cameras_path))
        kind = "forward-facing" if est.forward_facing else "360°"
        return {
            "up": est.up.tolist(),
            "up_source": "cameras",
            "up_confidence": None,
            "up_reason": f"training cameras ({kind})",
        }
    pts, w = scene_points(scene)
    su = estimate_scene_up(
        pts, w, frame.center, frame.radius, up=None if up is None else np.asarray(up)
    )
    return {
        "up": su.up.tolist(),
        "up_source": str(su.source),
        "up_confidence": su.confidence,
        "up_reason": su.reason,
    }


def run(args: argparse.Namespace) -> int:
    from ..io.load import load_scene, scene_cameras
    from ..scene_stats import scene_summary
    from ..segment_request import parse_up
    from ..views import scene_frame

    up = parse_up(args.up)
    # nothing here reads the SH beyond the DC, so none is loaded (GBs on large scenes)
    scene = load_scene(args.path, max_sh_degree=0, lod=args.lod)
    frame = scene_frame(scene)  # once, for the summary and the up estimate
    info = scene_summary(scene, frame)
    for k in ("lod_level", "lod_levels", "lod_counts"):  # a streamed LOD scene's levels
        if k in getattr(scene, "extras", {}):
            info[k] = scene.extras[k]
    cams = args.cameras
    if cams is None and (args.path.parent / "cameras.json").is_file():
        cams = args.path.parent / "cameras.json"
    own = scene_cameras(scene)
    if cams is not None:
        info.update(_cameras_info(cams))
    else:
        info["camera_count"] = len(own)
        if own:
            info["cameras_file"] = "scene file"
    info.update(_up_info(scene, cams, up, frame))
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

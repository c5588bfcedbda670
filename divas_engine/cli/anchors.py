"""``divas anchors SCENE [--cameras C] [--all] [--up X,Y,Z] [--device D] --out DIR``.

Writes ``DIR/anchors.json`` (the :class:`~divas_engine.views.AnchorPlan`: each
anchor's camera in the ``Camera.to_dict`` schema, direction, score, unsupported,
source; ``scene_up`` when camera-free: the up, its source, confidence and reason) and
one PNG render per offered anchor (``DIR/NN_<name>.png``). Prints the up and its
confidence.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..output_paths import check_output_path, write_image_atomic, write_json_atomic
from ..segment_request import parse_up


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("anchors", help="pick the anchor views of a scene and render them")
    p.add_argument(
        "scene", type=Path, help="scene: .ply (2DGS/3DGS/compressed), .splat, .spz or .npz grid"
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="training cameras (default: cameras.json beside the scene, if any; "
        "none → camera-free anchors around the robust centre)",
    )
    p.add_argument(
        "--all",
        action="store_true",
        dest="all_views",
        help="offer every Fibonacci view (unsupported ones included), ranked",
    )
    p.add_argument(
        "--up",
        default=None,
        metavar="X,Y,Z",
        help="scene up direction (default: estimated — from the training cameras, else "
        "from a ground plane of the scene, else the capture convention -y)",
    )
    p.add_argument("--scale", type=float, default=1.0, help="render scale of the PNGs (default 1)")
    p.add_argument("--no-render", action="store_true", help="write anchors.json only")
    p.add_argument(
        "--device",
        default="auto",
        choices=("auto", "cpu", "cuda"),
        help="Warp device for the renders (default auto)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(func=run)


def up_line(plan, given: bool = False) -> str:
    """``up: [x, y, z] (source, confidence c): reason`` of an anchor plan (``given``:
    the up came from ``--up``)."""
    v = "[" + ", ".join(f"{x:.3g}" for x in plan.up) + "]"
    su = plan.scene_up
    if su is not None:
        return f"up: {v} ({su.source}, confidence {su.confidence:.2f}): {su.reason}"
    return f"up: {v} ({'given (--up)' if given else 'training cameras'})"


def make_renderer(scene, device):
    """The renderer for ``scene`` (the render package's factory when it has one)."""
    from .. import render as render_pkg

    factory = getattr(render_pkg, "make_renderer", None)
    if factory is not None:
        return factory(scene, device=device)
    from ..scene import SurfelScene

    if isinstance(scene, SurfelScene):
        from ..render.surfel_renderer import SurfelRenderer

        return SurfelRenderer(scene, device=device)
    return None


def run(args: argparse.Namespace) -> int:
    from ..io.cameras import load_cameras
    from ..io.load import load_scene, scene_cameras
    from ..scene import SurfelScene
    from ..views import plan_scene_anchors, scene_frame

    if args.scale <= 0:
        raise DivasInputError(None, f"--scale must be positive, got {args.scale}")
    up = parse_up(args.up)
    check_output_path(args.out, what="--out", folder=True)
    scene = load_scene(args.scene)
    cams_path = args.cameras
    if cams_path is None and (args.scene.parent / "cameras.json").is_file():
        cams_path = args.scene.parent / "cameras.json"
    cameras = load_cameras(cams_path) if cams_path is not None else scene_cameras(scene)
    frame = scene_frame(scene)
    kind = SceneKind.GS2D if isinstance(scene, SurfelScene) else SceneKind.NERF
    plan = plan_scene_anchors(scene, cameras, kind=kind, all_views=args.all_views, up=up)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    doc = plan.to_dict()
    doc["scene"] = str(args.scene)
    doc["cameras_file"] = (
        str(cams_path) if cams_path is not None else ("scene file" if cameras else None)
    )
    doc["r_fg"] = frame.radius
    renderer = None if args.no_render else make_renderer(scene, args.device)
    if renderer is None and not args.no_render:
        print(
            "divas anchors: no renderer for this scene type yet; writing anchors.json only",
            file=sys.stderr,
        )
    for i, (a, entry) in enumerate(zip(plan.anchors, doc["anchors"])):
        if renderer is None:
            continue

        rgb = renderer.render(a.camera, scale=args.scale).rgb
        img = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        name = f"{i:02d}_{a.camera.name or a.source}.png"
        write_image_atomic(out / name, img[..., ::-1])
        entry["image"] = name
    write_json_atomic(out / "anchors.json", doc)
    print(up_line(plan, given=up is not None))
    print(
        f"{len(plan.anchors)} anchors ({'camera-free' if plan.camera_free else len(cameras)} "
        f"{'' if plan.camera_free else 'training cameras, '}"
        f"{'forward-facing' if plan.forward_facing else '360°'}) → {out / 'anchors.json'}"
    )
    return 0


__all__ = ["add_parser", "run", "make_renderer", "up_line", "parse_up"]

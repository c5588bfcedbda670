"""``divas demo [--out DIR]``: the whole pipeline on a synthetic scene, end to end.

1. generate a synthetic scene (default ``ribs``, 50k surfels) into ``DIR/scene``;
2. write ``DIR/prompts.json`` from its metadata click points: each click goes on
   ``--views-per-click`` (3) training cameras that see it (spread over the rig), one
   anchor per camera, one centroid view per (click, camera);
3. segment it headless (``divas segment``; the weight-free graph3d segmenter by
   default) → ``DIR/segmented.ply``, ``DIR/labels.npy``, ``DIR/report.json``;
4. render the selection recoloured over each test camera → ``DIR/overlay_<cam>.png``,
   and ``DIR/demo.png``: the first test cameras side by side, render | selection;
5. print the IoU against ground truth at the test cameras (NOTES "Evaluation":
   predicted = render of the per-surfel indicator ≥ 0.1, ground truth = render of the
   ground-truth labels ≥ 0.5), also stored in the report under ``evaluation.render``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..kinds import ViewStatus
from ..output_paths import check_output_path, write_image_atomic
from .segment import advice_suffix


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..synthetic import SCENE_NAMES

    p = sub.add_parser(
        "demo",
        help="generate a synthetic scene, segment it, print the IoU",
        description="End-to-end demo on a synthetic scene with ground truth.",
    )
    p.add_argument("--scene", choices=SCENE_NAMES, default="ribs", help="synthetic scene (ribs)")
    p.add_argument("--size", type=int, default=50_000, help="surfels (default 50000)")
    p.add_argument("--seed", type=int, default=0, help="scene and segmenter seed (default 0)")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    p.add_argument(
        "--segmenter",
        choices=("graph3d", "classic", "oracle"),
        default="graph3d",
        help="graph3d (default, weight-free 3D cut), classic (weight-free GrabCut) or the "
        "SAM-like oracle",
    )
    p.add_argument(
        "--views-per-click",
        type=int,
        default=3,
        help="training cameras (anchors) per metadata click point (default 3)",
    )
    p.add_argument(
        "--mask-channel",
        type=int,
        default=1,
        choices=(0, 1, 2),
        help="segmenter channel kept (default 1, the paper's)",
    )
    p.add_argument("--scale", type=float, default=1.0, help="render scale (default 1)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    from ..evaluation.demo_prompts import demo_prompts
    from ..evaluation.metrics import EvalConfig, evaluate_selection
    from ..evaluation.render_scores import MaskScores
    from ..io.cameras import load_cameras
    from ..segment_request import SegmentRequest
    from ..synthetic import MIN_SIZE, generate_scene
    from .segment import segment_scene, write_report

    if args.size < MIN_SIZE:
        raise DivasInputError(None, f"--size {args.size} is too small (minimum {MIN_SIZE})")
    t0 = time.perf_counter()
    out: Path = args.out
    check_output_path(out, what="--out", folder=True)
    out.mkdir(parents=True, exist_ok=True)
    sc = generate_scene(args.scene, out / "scene", size=args.size, seed=args.seed)
    print(
        f"generated {args.scene} ({len(sc.scene)} surfels, {len(sc.metadata['clicks'])} click "
        f"points) in {time.perf_counter() - t0:.1f} s → {out / 'scene'}"
    )
    prompts = demo_prompts(sc.metadata, sc.cameras, args.views_per_click)
    prompts_path = out / "prompts.json"
    prompts.write(prompts_path)
    report, session = segment_scene(  # what the user would pass to `divas segment`
        SegmentRequest(
            out / "scene" / "scene.ply",
            prompts_path,
            cameras=out / "scene" / "cameras.json",
            out=out / "segmented.ply",
            labels_out=out / "labels.npy",
            segmenter=args.segmenter,
            gt_labels=out / "scene" / "labels.npy",
            scale=args.scale,
            device=args.device,
            seed=args.seed,
            mask_channel=args.mask_channel,
        ),
        progress=not args.no_progress,
        keep_session=True,
    )
    try:
        test_cams = load_cameras(out / "scene" / "test_cameras.json")
        gt = np.load(out / "scene" / "labels.npy")[session.scene.source.kept_rows]
        t = time.perf_counter()
        scores = MaskScores.from_scene_scores(
            evaluate_selection(
                session.scene,
                test_cams,
                session.selection,
                gt,
                config=EvalConfig(scale=args.scale),
                renderer=session.renderer,
            )
        )
        pairs = []
        for cam in test_cams:
            ov = session.overlay(cam)
            img = (np.clip(ov.image, 0, 1) * 255 + 0.5).astype(np.uint8)
            write_image_atomic(out / f"overlay_{cam.name}.png", img[..., ::-1])
            if len(pairs) < _SIDE_BY_SIDE_ROWS:
                rgb = session.renderer.render(session.working_camera(cam)).rgb
                pairs.append(np.hstack([_u8(rgb), img]))
        picture = out / "demo.png"
        write_image_atomic(picture, np.vstack(pairs)[..., ::-1])
        report.setdefault("evaluation", {})["render"] = scores.as_dict()
        report["timings"]["evaluation_s"] = time.perf_counter() - t
        report["timings"]["demo_total_s"] = time.perf_counter() - t0
        write_report(out / "report.json", report)
    finally:
        session.close()
    c = report["counts"]
    print(
        f"segmented with {args.segmenter}: {c['accepted']} of {c['centroid_views']} centroid "
        f"views fused, {c['selected']} surfels selected → {out / 'segmented.ply'}"
    )
    for v in report["views"]:
        if v["status"] == ViewStatus.REJECTED:
            print(f"  rejected {v['id']}: {v['reason']}" + advice_suffix(v.get("advice")))
    e3 = report["evaluation"]["surfels"]
    print(f"3D: precision {e3['precision']:.3f}, recall {e3['recall']:.3f}, IoU {e3['iou']:.3f}")
    print(
        f"IoU at {len(test_cams)} test cameras (NOTES 'Evaluation'): mean {scores.iou:.3f} "
        f"(precision {scores.precision:.3f}, recall {scores.recall:.3f}); overlays → "
        f"{out}/overlay_*.png; report → {out / 'report.json'}; "
        f"total {time.perf_counter() - t0:.1f} s"
    )
    print(f"picture (render | selection) → {picture}")
    return 0


#: Test cameras shown in ``demo.png`` (one row each: render | selection overlay).
_SIDE_BY_SIDE_ROWS = 2


def _u8(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)


__all__ = ["add_parser", "run"]

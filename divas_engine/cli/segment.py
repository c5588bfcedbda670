"""``divas segment SCENE --prompts P.json --out OUT``: headless segmentation from a prompts file.

Runs the whole DivAS loop (:class:`~divas_engine.session.Session`) on the anchors and
clicks of a prompts file (NOTES "Headless prompts file"): every positive click spawns a
centroid view, its default prompt plus ``centroid_prompts`` go to the segmenter, every
view is accepted in order (NeRF: asynchronous SAM with group synchronisation, Sec. 3.4),
then the selection is written in the input's format (a PLY subset / a masked ``.npz``
grid), optionally with per-input-row labels (``--labels-out``) and a JSON report.

Report (``--report``) keys:

* ``version`` (1), ``command``, ``scene``, ``cameras``, ``prompts``, ``kind`` ("2dgs"/"nerf"),
  ``segmenter``, ``seed``, ``device``, ``render_scale``, ``preset`` (NeRF);
* ``timings``: ``T_pipe_s`` (load → outputs written), ``load_s``, ``open_s``, ``export_s``
  and per stage (``render``, ``centroid``, ``segmenter``, ``segmenter_wait``, ``kernel``,
  ``mapping``, ``overlay``) ``{calls, total_s, mean_s, max_s, per_call_s}``;
* ``updates``: one record per accepted view (seconds by stage);
* ``counts``: primitives, anchors, centroid_views, accepted, rejected, selected,
  active_voxels, segmented_voxels …;
* ``views``: id, anchor, click, status (``fused``/``rejected``), reason, advice (the
  segmenter's hint: what to click next), score, strategy;
* ``memory``: ``peak_rss_bytes`` (and ``rss_bytes``);
* ``config``: the full session config; ``outputs``: files written;
* ``evaluation`` (with ``--gt-labels``): 3D precision / recall / IoU of the selection;
  on surfel scenes ``render``: image IoU, alpha fidelity, opacity-weighted IoU and
  extracted-object PSNR at test views around the ground truth (also
  ``without_completion`` on 3DGS scenes);
  ``oracle`` (oracle segmenter): its config and seed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind, ViewStatus
from ..output_paths import check_outputs, write_json_atomic
from .anchors import parse_up

SEGMENTERS = ("graph3d", "classic", "sam-onnx", "sam-torch", "oracle")  # SegmenterKind values


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "segment",
        help="segment a scene headless from a prompts file",
        description="Run the DivAS loop on the anchors/clicks of a prompts file "
        "(NOTES 'Headless prompts file') and write the selection.",
    )
    p.add_argument(
        "scene",
        type=Path,
        help="scene: .ply (2DGS/3DGS/compressed), .splat, .spz or .npz density grid",
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="training cameras (default: cameras.json beside the scene, if any)",
    )
    p.add_argument("--prompts", type=Path, required=True, help="prompts file (JSON, version 1)")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="output: the selected primitives (PLY subset / same format), or the "
        "masked grid .npz for NeRF scenes",
    )
    p.add_argument(
        "--labels-out", type=Path, default=None, help="bool .npy per input row (NeRF: [D,H,W] bool)"
    )
    p.add_argument(
        "--segmenter",
        choices=SEGMENTERS,
        default="graph3d",
        help="mask source (default graph3d: weight-free 3D cut over the scene's primitives; "
        "classic: GrabCut on colour + depth; oracle is for evaluation only)",
    )
    p.add_argument("--sam-encoder", type=Path, default=None, help="SAM ONNX image encoder")
    p.add_argument("--sam-decoder", type=Path, default=None, help="SAM ONNX prompt decoder")
    p.add_argument("--sam-checkpoint", type=Path, default=None, help="SAM PyTorch checkpoint")
    p.add_argument("--sam-model-type", default="vit_h", help="SAM model type (default vit_h)")
    p.add_argument(
        "--gt-labels",
        type=Path,
        default=None,
        help="ground truth .npy (bool per surfel / input row; NeRF [D,H,W] bool): "
        "the oracle's target, and a 3D score in the report",
    )
    p.add_argument(
        "--preset",
        choices=("llff", "mip360"),
        default=None,
        help="NeRF fusion preset (default: llff for forward-facing captures)",
    )
    p.add_argument(
        "--scale", type=float, default=1.0, help="render scale of every view (default 1)"
    )
    p.add_argument(
        "--grid-views",
        action="store_true",
        help="instant-ngp snapshots: march the density grid (the network's colour baked in) "
        "instead of rendering views from the network (much faster on a CPU)",
    )
    p.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help="Warp device (default auto)",
    )
    p.add_argument("--report", type=Path, default=None, help="write a JSON report here")
    p.add_argument(
        "--session",
        type=Path,
        default=None,
        help="save the session here (JSON + a content-addressed .npz; autosaved after "
        "open, every click and every accept)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the run killed while saving to --session: replay what it saved, "
        "then run the remaining prompts (a missing session file starts afresh)",
    )
    p.add_argument(
        "--mask-channel",
        type=int,
        default=1,
        choices=(0, 1, 2),
        help="segmenter channel kept (default 1, the paper's mid granularity)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the segmenter (default 0)")
    p.add_argument(
        "--up",
        default=None,
        metavar="X,Y,Z",
        help="scene up for the planned (fibonacci) anchors (default: estimated)",
    )
    p.add_argument(
        "--no-completion",
        action="store_true",
        help="3DGS scenes: the paper's selection only, without the completion of "
        "volumetric scenes (beyond the paper, issue 15)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _progress(iterable=None, *, total=None, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        file=sys.stderr,
        disable=not enabled,
        leave=False,
        dynamic_ncols=True,
    )


#: the flag that sets each of a segmenter's requirements (:class:`SegmenterSetupError`).
_FLAGS = {
    "ground_truth": "--gt-labels",
    "sam_encoder": "--sam-encoder",
    "sam_decoder": "--sam-decoder",
    "sam_checkpoint": "--sam-checkpoint",
}


def _segmenter(settings, *, has_ground_truth: bool):
    """The engine's segmenter; what it lacks is named by this command's flags."""
    from ..segment import SegmenterSetupError, build_segmenter

    try:
        return build_segmenter(settings, has_ground_truth=has_ground_truth)
    except SegmenterSetupError as e:
        flags = " and ".join(_FLAGS[r] for r in e.requires)
        raise DivasInputError(None, f"--segmenter {e.kind} needs {flags}") from None


def _device(name: str):
    from divas_kernels import resolve_device

    try:
        return resolve_device(name)
    except RuntimeError as e:
        raise DivasInputError(None, str(e)) from None


def segment_scene(
    scene_path: Path,
    prompts_path: Path | Any,
    *,
    cameras_path: Path | None = None,
    out: Path | None = None,
    labels_out: Path | None = None,
    segmenter: str = "graph3d",
    sam_encoder: Path | None = None,
    sam_decoder: Path | None = None,
    sam_checkpoint: Path | None = None,
    sam_model_type: str = "vit_h",
    gt_labels: Path | None = None,
    preset: str | None = None,
    scale: float = 1.0,
    device: str = "auto",
    session_path: Path | None = None,
    seed: int = 0,
    progress: bool = True,
    keep_session: bool = False,
    mask_channel: int = 1,
    up: Sequence[float] | None = None,
    completion: bool = True,
    resume: bool = False,
    report_path: Path | None = None,
    grid_views: bool = False,
) -> tuple[dict[str, Any], Any]:
    """The whole ``divas segment`` pipeline; returns ``(report, session)``.

    ``prompts_path`` may also be a parsed :class:`~divas_engine.session.Prompts`. The
    session is closed unless ``keep_session``. Every output path (``out``,
    ``labels_out``, ``session_path``, ``report_path``) is checked before anything is
    loaded (:func:`~divas_engine.output_paths.check_outputs`). ``resume``: continue the
    run saved at ``session_path`` — replay it (``Session.load``, checked to be this run's
    by :func:`_check_resumable`), reuse its clicks and accepted views, run the rest.
    """
    from ..evaluation.ground_truth import load_ground_truth
    from ..evaluation.session_scores import session_evaluation
    from ..io.cameras import load_cameras
    from ..io.load import load_scene, scene_cameras
    from ..segment import SegmenterSettings
    from ..session import Prompts, Session, SessionConfig, anchor_plan, load_prompts
    from ..session.prompts import resolve_anchors
    from ..views import ViewConfig

    t_start = time.perf_counter()
    if not (scale > 0 and np.isfinite(scale)):
        raise DivasInputError(None, f"--scale must be positive, got {scale}")
    if resume and session_path is None:
        raise DivasInputError(None, "--resume needs --session (the session to continue)")
    check_outputs(  # before any loading or computing (issue 14)
        [
            ("--out", out),
            ("--labels-out", labels_out),
            ("--session", session_path),
            ("--report", report_path),
        ],
        [
            scene_path,
            cameras_path,
            prompts_path if isinstance(prompts_path, (str, Path)) else None,
            gt_labels,
            sam_encoder,
            sam_decoder,
            sam_checkpoint,
        ],
    )
    prompts = prompts_path if isinstance(prompts_path, Prompts) else load_prompts(prompts_path)
    dev = _device(device)
    scene = load_scene(scene_path)
    if cameras_path is None and (Path(scene_path).parent / "cameras.json").is_file():
        cameras_path = Path(scene_path).parent / "cameras.json"
    cameras = load_cameras(cameras_path) if cameras_path is not None else scene_cameras(scene)
    gt = load_ground_truth(gt_labels, scene) if gt_labels is not None else None
    seg = _segmenter(
        SegmenterSettings(
            segmenter,
            seed=seed,
            sam_encoder=sam_encoder,
            sam_decoder=sam_decoder,
            sam_checkpoint=sam_checkpoint,
            sam_model_type=sam_model_type,
            device=device,
        ),
        has_ground_truth=gt is not None,
    )
    if mask_channel not in (0, 1, 2):
        raise DivasInputError(None, f"--mask-channel must be 0, 1 or 2, got {mask_channel}")
    config = SessionConfig(
        view=ViewConfig(up=None if up is None else tuple(float(x) for x in up)),
        render_scale=float(scale),
        nerf_preset=preset,
        seed=int(seed),
        mask_channel=int(mask_channel),
        autosave=None if session_path is None else str(session_path),
    )
    if grid_views:
        from dataclasses import replace

        config = replace(config, render=replace(config.render, nerf_network=False))
    if not completion:
        from dataclasses import replace

        config = replace(
            config,
            mapping=replace(
                config.mapping, completion=replace(config.mapping.completion, enabled=False)
            ),
        )
    resolved = resolve_anchors(
        prompts, cameras, lambda: [a.camera for a in anchor_plan(scene, cameras, config).candidates]
    )
    t_load = time.perf_counter() - t_start
    t = time.perf_counter()
    if resume and Path(session_path).exists():
        session = Session.load(
            session_path, scene, seg, dev, cameras=cameras, gt_values=gt, autosave=session_path
        )
        try:
            _check_resumable(session, config, resolved, session_path)
        except BaseException:
            session.close()
            raise
    else:
        session = Session.open(
            scene,
            cameras,
            config,
            seg,
            dev,
            anchors=[(r.camera, r.source, r.index) for r in resolved],
            gt_values=gt,
            render_anchors=False,
        )
    try:
        for a in _progress(session.anchors, desc="anchors", enabled=progress):
            _ = a.buffers
        t_open = time.perf_counter() - t
        # spawn every centroid view first (bad clicks fail before the expensive part)
        spawned = []
        n_clicks = sum(len(r.prompt.clicks) for r in resolved)
        bar = _progress(total=n_clicks, desc="centroid views", enabled=progress)
        for i, r in enumerate(resolved):
            a = session.anchors[i]
            saved = session.current.clicks.get(i, [])  # a resumed session's clicks
            for k, c in enumerate(r.prompt.clicks):
                try:
                    xy = a.full_camera.pixels_to(a.camera, c.xy)
                    xy = (float(xy[0]), float(xy[1]))
                    if k < len(saved):
                        v = _saved_click(session, saved[k], xy, c.positive, session_path)
                    else:
                        v = session.click(i, xy, positive=c.positive)
                except DivasInputError as e:
                    raise DivasInputError(
                        prompts.source, f"anchors[{i}].clicks[{k}]: {e.problem}"
                    ) from None
                if c.positive:
                    extra = prompts.extra_points(i, k)
                    pts = a.full_camera.pixels_to(
                        a.camera, np.array([p.xy for p in extra]).reshape(-1, 2)
                    )
                    labs = np.array([1 if p.positive else 0 for p in extra], np.int64)
                    spawned.append((v, pts, labs))
                bar.update(1)
        bar.close()
        for v, pts, labs in _progress(spawned, desc="fusion", enabled=progress):
            if v.status == ViewStatus.OPEN:  # a resumed session's accepted views are done
                session.accept(v, pts, labs)
        session.sync()
        # outputs
        t = time.perf_counter()
        outputs: dict[str, Any] = {}
        error = None
        sel = session.selection
        if out is not None:
            if not sel.any():
                reasons = "; ".join(
                    f"{v.id}: {v.reason}{advice_suffix(v.advice)}"
                    for v, _, _ in spawned
                    if v.status == ViewStatus.REJECTED
                )
                error = "the selection is empty; nothing to write" + (
                    f" (rejected views: {reasons})" if reasons else ""
                )
            else:
                res = session.export(out, labels_path=labels_out)
                outputs.update({"out": str(res.path), "format": res.format, "count": res.count})
                if res.labels_path is not None:
                    outputs["labels_out"] = str(res.labels_path)
        if session_path is not None:
            session.save(session_path)
            outputs["session"] = str(session_path)
        t_export = time.perf_counter() - t
        rep = session.report()
        timings = rep.pop("timings")
        timings.update(
            {
                "T_pipe_s": time.perf_counter() - t_start,
                "load_s": t_load,
                "open_s": t_open,
                "export_s": t_export,
            }
        )
        report: dict[str, Any] = {
            "version": 1,
            "command": "segment",
            "scene": str(scene_path),
            "cameras": None if cameras_path is None else str(cameras_path),
            "prompts": prompts.source,
            "kind": rep["kind"],
            "segmenter": segmenter,
            "seed": int(seed),
            "device": rep["device"],
            "render_scale": float(scale),
            "timings": timings,
            **{k: v for k, v in rep.items() if k not in ("kind", "seed", "device", "segmenter")},
            "outputs": outputs,
        }
        if session.kind == SceneKind.NERF:
            report["preset"] = session.preset
        if gt is not None:
            report["evaluation"] = session_evaluation(session, sel, gt, dev)
        if segmenter == "oracle":
            from dataclasses import asdict

            report["oracle"] = {"config": asdict(seg.config), "seed": seg.config.seed}
        if error is not None:
            report["error"] = error
            exc = DivasInputError(None, error)
            exc.report = report  # type: ignore[attr-defined]
            raise exc
        return report, session
    finally:
        if not keep_session:
            session.close()


def advice_suffix(advice: str | None) -> str:
    """The segmenter's hint for a rejected view (what to click next), as a suffix."""
    return f" — {advice}" if advice else ""


def _check_resumable(session, config, resolved, path) -> None:
    """A saved session continues this run only if it was made by the same command:
    the same settings and the same anchors, one unfinished object."""
    saved = {k: v for k, v in session.config.to_dict().items() if k != "autosave"}
    wanted = {k: v for k, v in config.to_dict().items() if k != "autosave"}
    if json.dumps(saved, sort_keys=True) != json.dumps(wanted, sort_keys=True):
        diff = sorted(k for k in wanted if saved.get(k) != wanted.get(k))
        raise DivasInputError(
            path, f"cannot resume: saved with other settings ({', '.join(diff) or 'config'})"
        )
    cams = [json.dumps(a.full_camera.to_dict(), sort_keys=True) for a in session.anchors]
    want = [json.dumps(r.camera.to_dict(), sort_keys=True) for r in resolved]
    if cams != want:
        raise DivasInputError(path, "cannot resume: the session's anchors are not the prompts'")
    if len(session.objects) != 1:
        raise DivasInputError(path, "cannot resume: the session holds finished objects")


def _saved_click(session, rec, xy, positive: bool, path):
    """The view (positive) or record (negative) of a click a resumed session already
    made; it must be the prompts file's click."""
    same = rec.positive == positive and np.allclose(rec.xy, xy, rtol=0, atol=1e-6)
    if not same:
        raise DivasInputError(path, "cannot resume: the session's clicks are not the prompts'")
    return session.view(rec.view_id) if positive else rec


def write_report(path: Path, report: dict[str, Any]) -> None:
    write_json_atomic(path, report, default=_json_default)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def run(args: argparse.Namespace) -> int:
    try:
        report, _ = segment_scene(
            args.scene,
            args.prompts,
            cameras_path=args.cameras,
            out=args.out,
            labels_out=args.labels_out,
            segmenter=args.segmenter,
            sam_encoder=args.sam_encoder,
            sam_decoder=args.sam_decoder,
            sam_checkpoint=args.sam_checkpoint,
            sam_model_type=args.sam_model_type,
            gt_labels=args.gt_labels,
            preset=args.preset,
            scale=args.scale,
            device=args.device,
            session_path=args.session,
            seed=args.seed,
            progress=not args.no_progress,
            mask_channel=args.mask_channel,
            up=parse_up(args.up),
            completion=not args.no_completion,
            resume=args.resume,
            report_path=args.report,
            grid_views=args.grid_views,
        )
    except DivasInputError as e:
        if args.report is not None and getattr(e, "report", None) is not None:
            write_report(args.report, e.report)  # the report says which views were rejected
        raise
    if args.report is not None:
        write_report(args.report, report)
    c = report["counts"]
    print(
        f"{c['accepted']} of {c['centroid_views']} centroid views fused "
        f"({c['rejected']} rejected); {c['selected']} "
        f"{'surfels' if report['kind'] == SceneKind.GS2D else 'voxels'} selected → {args.out} "
        f"({report['timings']['T_pipe_s']:.1f} s)"
    )
    for v in report["views"]:
        if v["status"] == ViewStatus.REJECTED:
            print(f"  rejected {v['id']}: {v['reason']}" + advice_suffix(v.get("advice")))
    if "evaluation" in report:
        e = next(iter(report["evaluation"].values()))
        print(
            f"  vs ground truth: precision {e['precision']:.3f}, recall {e['recall']:.3f}, "
            f"IoU {e['iou']:.3f}"
        )
        r = report["evaluation"].get("render") or {}
        for k in ("selection", "without_completion"):
            if k in r:
                x = r[k]
                print(
                    f"  {k} at {r['test_views']} test views: image IoU {x['image_iou']:.3f}, "
                    f"alpha fidelity {x['alpha_fidelity']:.3f}, opacity-weighted IoU "
                    f"{x['opacity_weighted_iou']:.3f}, PSNR {x['psnr']:.2f} dB"
                )
    return 0


__all__ = ["add_parser", "advice_suffix", "run", "segment_scene", "write_report"]

"""``divas segment SCENE --prompts P.json --out OUT``: headless segmentation from a prompts file.

Runs the whole DivAS loop (:class:`~divas_engine.session.Session`) on the anchors and clicks of
a prompts file (NOTES "Headless prompts file"): every positive click spawns a centroid view,
its prompts go to the segmenter, every view is accepted in order (NeRF: asynchronous SAM with
group synchronisation, Sec. 3.4), then the selection is written in the input's format,
optionally with per-input-row labels (``--labels-out``) and a JSON report.

Report (``--report``) keys: ``version`` (1), the inputs and settings (``command``, ``scene``,
``kind``, ``segmenter``, ``seed``, ``device`` …); ``timings`` (``T_pipe_s`` and per stage
``{calls, total_s, mean_s, max_s, per_call_s}``); ``updates`` (per accepted view);
``counts``; ``views`` (id, anchor, click, status, reason, advice, score, strategy);
``memory``; ``config``; ``outputs``; ``points`` (where each 3D point was clicked,
:func:`points_report`); ``evaluation`` (with ``--gt-labels``: 3D precision / recall / IoU and,
on surfel scenes, rendered metrics, also ``without_completion`` on 3DGS); ``oracle``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind, ViewStatus
from ..output_paths import check_outputs, write_json_atomic
from ..segment_request import SegmentRequest, add_request_arguments


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "segment",
        help="segment a scene headless from a prompts file",
        description="Run the DivAS loop on the anchors/clicks of a prompts file "
        "(NOTES 'Headless prompts file') and write the selection.",
    )
    add_request_arguments(p)
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
    request: SegmentRequest, *, progress: bool = True, keep_session: bool = False
) -> tuple[dict[str, Any], Any]:
    """The whole ``divas segment`` pipeline for ``request``; returns ``(report, session)``.

    The session is closed unless ``keep_session``. Every output path (``out``,
    ``labels_out``, ``session``, ``report``) is checked before anything is loaded
    (:func:`~divas_engine.output_paths.check_outputs`). ``request.resume``: continue the
    run saved at ``request.session`` — replay it (``Session.load``, checked to be this
    run's by :func:`_check_resumable`), reuse its clicks and accepted views, run the rest.
    """
    from ..evaluation.ground_truth import load_ground_truth
    from ..evaluation.session_scores import session_evaluation
    from ..io.cameras import load_cameras
    from ..io.load import load_scene, scene_cameras
    from ..render import make_renderer
    from ..segment import SegmenterSettings
    from ..session import Session, SessionConfig, WideningConfig, anchor_plan, load_prompts
    from ..session.point_prompts import resolve_prompts
    from ..views import ViewConfig

    req = request
    t_start = time.perf_counter()
    req.check()
    check_outputs(  # before any loading or computing
        [
            ("--out", req.out),
            ("--labels-out", req.labels_out),
            ("--session", req.session),
            ("--report", req.report),
        ],
        [
            req.scene,
            req.cameras,
            req.prompts,
            req.gt_labels,
            req.sam_encoder,
            req.sam_decoder,
            req.sam_checkpoint,
        ],
    )
    prompts = load_prompts(req.prompts)
    dev = _device(req.device)
    scene = load_scene(req.scene, lod=req.lod)
    cameras_path = req.cameras
    if cameras_path is None and (req.scene.parent / "cameras.json").is_file():
        cameras_path = req.scene.parent / "cameras.json"
    cameras = load_cameras(cameras_path) if cameras_path is not None else scene_cameras(scene)
    gt = load_ground_truth(req.gt_labels, scene) if req.gt_labels is not None else None
    seg = _segmenter(
        SegmenterSettings(
            req.segmenter,
            seed=req.seed,
            sam_encoder=req.sam_encoder,
            sam_decoder=req.sam_decoder,
            sam_checkpoint=req.sam_checkpoint,
            sam_model_type=req.sam_model_type,
            device=req.device,
        ),
        has_ground_truth=gt is not None,
    )
    config = SessionConfig(
        view=ViewConfig(up=req.up),
        render_scale=float(req.scale),
        nerf_preset=req.preset,
        seed=int(req.seed),
        mask_channel=int(req.mask_channel),
        widening=WideningConfig(enabled=bool(req.widening)),
        autosave=None if req.session is None else str(req.session),
    )
    if req.nerf_network is not None:
        from dataclasses import replace

        config = replace(config, render=replace(config.render, nerf_network=req.nerf_network))
    if not req.completion:
        from dataclasses import replace

        config = replace(
            config,
            mapping=replace(
                config.mapping, completion=replace(config.mapping.completion, enabled=False)
            ),
        )
    renderer = None

    def render(camera):  # the session's renderer, made here when points need renders
        nonlocal renderer
        if renderer is None:
            renderer = make_renderer(scene, device=dev, config=config.render)
        return renderer.render(camera)

    resolved = resolve_prompts(
        prompts,
        scene,
        cameras,
        config,
        render,
        lambda: [a.camera for a in anchor_plan(scene, cameras, config).candidates],
    )
    t_load = time.perf_counter() - t_start
    t = time.perf_counter()
    session_path = req.session
    if req.resume and session_path.exists():
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
            renderer=renderer,
        )
    try:
        for a in _progress(session.anchors, desc="anchors", enabled=progress):
            session.render(a)
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
                    raise DivasInputError(prompts.source, f"{r.where(i, k)}: {e.problem}") from None
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
        if req.out is not None:
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
                res = session.export(req.out, labels_path=req.labels_out)
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
            "scene": str(req.scene),
            "cameras": None if cameras_path is None else str(cameras_path),
            "prompts": prompts.source,
            "kind": rep["kind"],
            "segmenter": req.segmenter,
            "seed": int(req.seed),
            "device": rep["device"],
            "render_scale": float(req.scale),
            "timings": timings,
            **{k: v for k, v in rep.items() if k not in ("kind", "seed", "device", "segmenter")},
            "outputs": outputs,
        }
        if session.kind == SceneKind.NERF:
            report["preset"] = session.preset
        if prompts.points:
            report["points"] = points_report(prompts, resolved)
        if gt is not None:
            report["evaluation"] = session_evaluation(session, sel, gt, dev)
        if req.segmenter == "oracle":
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


def points_report(prompts, resolved) -> list[dict[str, Any]]:
    """Where each 3D point of the prompts file was clicked: ``{point, xyz, positive,
    clicks: [{anchor, source, index, xy}]}`` (a negative point no picked anchor sees has
    no click)."""
    out = [
        {"point": j, "xyz": list(p.xyz), "positive": p.positive, "clicks": []}
        for j, p in enumerate(prompts.points)
    ]
    for i, r in enumerate(resolved):
        for j, c in zip(r.points or (), r.prompt.clicks):
            out[j]["clicks"].append(
                {"anchor": i, "source": r.source, "index": r.index, "xy": list(c.xy)}
            )
    return out


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
        report, _ = segment_scene(SegmentRequest.from_args(args), progress=not args.no_progress)
    except DivasInputError as e:
        if args.report is not None and getattr(e, "report", None) is not None:
            write_report(args.report, e.report)  # the report says which views were rejected
        raise
    if args.report is not None:
        write_report(args.report, report)
    c = report["counts"]
    wide = f", {c['wider_views']} of them wider" if c.get("wider_views") else ""
    print(
        f"{c['accepted']} of {c['centroid_views']} centroid views fused "
        f"({c['rejected']} rejected{wide}); {c['selected']} "
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

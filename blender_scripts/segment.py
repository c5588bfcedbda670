"""Headless DivAS segmentation in Blender, through the add-on's operators.

    blender -b --python blender_scripts/segment.py -- --scene S.ply --prompts P.json --out O.ply
    python blender_scripts/segment.py -- --scene S.ply --prompts P.json --out O.ply   # bpy module

The mirror of ``divas segment`` (same arguments, same outputs, the same labels), but
every step is an operator: ``divas.import_splats`` / ``divas.import_density_grid``,
``divas.start_session`` (anchors from the prompts file), one ``divas.session_click`` per
click and one ``divas.session_accept`` per positive click (spawned first, accepted in
order, like ``divas segment``), ``divas.session_sync`` and ``divas.export_selection``.
Click coordinates go to the operators as decimal text, so they reach the engine in
double precision.

Arguments follow ``--`` (all of ``sys.argv`` without it). Exit status: 0 on success, 1
with a one-line ``error:`` message on a failure, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import importlib
import json
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SEGMENTERS = {
    "graph3d": "graph3d",
    "classic": "classic",
    "sam-onnx": "sam-onnx",
    "sam-torch": "sam-torch",
    "oracle": "oracle",
}


class ScriptError(Exception):
    """A failure reported as one line (exit status 1)."""


def _request_module():
    """``divas_engine.segment_request``: the engine beside the add-on, else this repository's."""
    try:
        return importlib.import_module("divas_engine.segment_request")
    except ImportError:
        sys.path.append(str(REPO))
        return importlib.import_module("divas_engine.segment_request")


#: ``divas segment`` arguments the add-on's operators do not take.
_NOT_OFFERED = frozenset({"resume", "up", "completion", "widening", "lod"})


def parse_args(argv: list[str]) -> argparse.Namespace:
    """``divas segment``'s arguments (``--scene`` for the scene), ``--min-opacity``, and
    the :class:`SegmentRequest` they make as ``request``."""
    requests = _request_module()
    p = argparse.ArgumentParser(
        prog="blender -b --python blender_scripts/segment.py --",
        description="Segment a scene headless through the DivAS "
        "add-on's operators (mirrors `divas segment`).",
    )
    requests.add_request_arguments(p, scene_option=True, omit=_NOT_OFFERED)
    p.add_argument(
        "--min-opacity",
        type=float,
        default=0.0,
        help="NeRF grids: voxels imported as points (0, every voxel, keeps the "
        "export identical to `divas segment`)",
    )
    args = p.parse_args(argv)
    args.request = requests.SegmentRequest.from_args(args)
    return args


def script_argv(argv: list[str]) -> list[str]:
    """The arguments after ``--`` (Blender passes its own before it)."""
    return argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]


def enable_addon():
    """The add-on's package: the one already enabled (an installed extension), else
    ``blender_addon`` from this repository."""
    import bpy

    if not hasattr(bpy.types, "DIVAS_OT_start_session"):
        if str(REPO) not in sys.path:
            sys.path.insert(0, str(REPO))
        import addon_utils

        if addon_utils.enable("blender_addon", default_set=True) is None:
            raise ScriptError("could not enable the DivAS add-on (blender_addon)")
    module = bpy.types.DIVAS_OT_start_session.__module__
    return importlib.import_module(module.rsplit(".operators", 1)[0])


def _op(call, what: str, **kw) -> None:
    """Run an operator; its reported error (Blender raises it as RuntimeError) → ScriptError."""
    try:
        result = call(**kw)
    except RuntimeError as e:
        msg = str(e).strip()
        msg = msg.split("Error: ", 1)[-1].strip() if "Error: " in msg else msg
        raise ScriptError(f"{what}: {msg}") from None
    if "FINISHED" not in result:
        raise ScriptError(f"{what}: cancelled")


def _xy(xy) -> str:
    return f"{xy[0]!r} {xy[1]!r}"


def run(args: argparse.Namespace) -> dict:
    t_start = time.perf_counter()
    req = args.request
    import bpy

    addon = enable_addon()
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from divas_engine.cli.segment import write_report
    from divas_engine.errors import DivasInputError
    from divas_engine.evaluation.ground_truth import load_ground_truth
    from divas_engine.evaluation.session_scores import session_evaluation
    from divas_engine.kinds import SceneKind
    from divas_engine.output_paths import check_outputs
    from divas_engine.session import load_prompts

    registry = importlib.import_module(f"{addon.__name__}.session_registry")
    properties = importlib.import_module(f"{addon.__name__}.properties")
    view_prop = importlib.import_module(f"{addon.__name__}.modal_logic").VIEW_PROP
    scale_prop = properties.DIVAS_PG_session_settings.bl_rna.properties["render_scale"]
    if not scale_prop.hard_min <= req.scale <= scale_prop.hard_max:
        raise ScriptError(
            f"--scale must be in [{scale_prop.hard_min:g}, "
            f"{scale_prop.hard_max:g}], got {req.scale}"
        )
    if req.segmenter == "sam-onnx" and (req.sam_encoder is None or req.sam_decoder is None):
        raise ScriptError("--segmenter sam-onnx needs --sam-encoder and --sam-decoder")
    if req.segmenter == "sam-torch" and req.sam_checkpoint is None:
        raise ScriptError("--segmenter sam-torch needs --sam-checkpoint")
    if req.seed < 0:
        raise ScriptError(f"--seed must be ≥ 0, got {req.seed}")
    try:  # every output checked before anything is loaded, as `divas segment`
        check_outputs(
            [
                ("--out", req.out),
                ("--labels-out", req.labels_out),
                ("--session", req.session),
                ("--report", req.report),
            ],
            [req.scene, req.cameras, req.prompts, req.gt_labels],
        )
    except DivasInputError as e:
        raise ScriptError(str(e)) from None
    prompts = load_prompts(req.prompts)
    if prompts.points:
        raise ScriptError(
            f"{req.prompts}: 3D 'points' are clicked by `divas segment` / `divas batch`; "
            "this script clicks the file's anchors only"
        )
    ops = bpy.ops.divas
    is_grid = req.scene.suffix.lower() == ".npz"
    t = time.perf_counter()
    if is_grid:
        _op(
            ops.import_density_grid,
            "import",
            filepath=str(req.scene),
            display=False,
            min_opacity=args.min_opacity,
        )
    else:
        _op(ops.import_splats, "import", filepath=str(req.scene), display=False)
    t_import = time.perf_counter() - t
    obj = bpy.context.active_object
    props = bpy.context.scene.divas
    props.render_scale, props.seed, props.mask_channel = req.scale, req.seed, req.mask_channel
    props.preset = properties.preset_from_cli(req.preset if is_grid else None)
    props.autosave = req.session is not None
    prefs = addon.preferences.get_preferences(bpy.context)
    if req.segmenter.startswith("sam") and prefs is not None:
        prefs.sam_encoder_path = str(req.sam_encoder or "")
        prefs.sam_decoder_path = str(req.sam_decoder or "")
        prefs.sam_checkpoint_path = str(req.sam_checkpoint or "")
        prefs.sam_model_type = req.sam_model_type
    t = time.perf_counter()
    _op(
        ops.start_session,
        "start",
        segmenter=SEGMENTERS[req.segmenter],
        device=req.device,
        cameras=str(req.cameras or ""),
        prompts=str(req.prompts),
        gt_labels=str(req.gt_labels or ""),
        autosave=str(req.session or ""),
    )
    t_start_session = time.perf_counter() - t
    live = registry.get(obj)
    # every click first (bad clicks fail before the expensive part), then accept in order
    spawned = []
    for i, a in enumerate(prompts.anchors):
        for k, c in enumerate(a.clicks):
            _op(
                ops.session_click,
                f"anchors[{i}].clicks[{k}]",
                anchor=i,
                xy=_xy(c.xy),
                positive=c.positive,
                full_resolution=True,
                preview=False,
            )
            if c.positive:
                vid = bpy.context.scene.camera.get(view_prop)  # the view just spawned
                pts = [[p.xy[0], p.xy[1], p.positive] for p in prompts.extra_points(i, k)]
                spawned.append((vid, pts))
    for vid, pts in spawned:
        _op(
            ops.session_accept,
            f"accept {vid}",
            view=vid,
            points=json.dumps(pts),
            full_resolution=True,
        )
    _op(ops.session_sync, "sync")
    session = live.session
    t = time.perf_counter()
    outputs: dict = {}
    error = None
    if not session.selection.any():
        reasons = "; ".join(f"{v.id}: {v.reason}" for v in session.views if v.status == "rejected")
        error = "the selection is empty; nothing to write" + (
            f" (rejected views: {reasons})" if reasons else ""
        )
    else:
        _op(
            ops.export_selection,
            "export",
            filepath=str(req.out),
            write_labels=req.labels_out is not None,
        )
        out = (
            req.out
            if req.out.suffix
            else req.out.with_suffix(
                addon.source.FORMAT_SUFFIX.get(obj.get(addon.source.FORMAT_PROP, ""), ".ply")
            )
        )
        outputs.update({"out": str(out), "count": int(session.selection.sum())})
        if req.labels_out is not None:
            made = out.with_name(out.name.split(".")[0] + "_labels.npy")
            if made.resolve() != req.labels_out.resolve():
                shutil.move(str(made), str(req.labels_out))
            outputs["labels_out"] = str(req.labels_out)
    if req.session is not None:
        session.save(req.session)
        outputs["session"] = str(req.session)
    t_export = time.perf_counter() - t
    rep = session.report()
    timings = rep.pop("timings")
    timings.update(
        {
            "T_pipe_s": time.perf_counter() - t_start,
            "import_s": t_import,
            "start_s": t_start_session,
            "export_s": t_export,
        }
    )
    report = {
        "version": 1,
        "command": "blender segment",
        "blender": bpy.app.version_string,
        "scene": str(req.scene),
        "cameras": None if req.cameras is None else str(req.cameras),
        "prompts": str(req.prompts),
        "kind": rep["kind"],
        "segmenter": req.segmenter,
        "seed": req.seed,
        "device": rep["device"],
        "render_scale": req.scale,
        "timings": timings,
        **{k: v for k, v in rep.items() if k not in ("kind", "seed", "device", "segmenter")},
        "outputs": outputs,
    }
    if session.kind == SceneKind.NERF:
        report["preset"] = session.preset
    if req.gt_labels is not None:
        gt = load_ground_truth(req.gt_labels, session.scene)
        report["evaluation"] = session_evaluation(session, session.selection, gt, session.device)
    if req.report is not None:
        write_report(req.report, report)
    if error is not None:
        raise ScriptError(error)
    return report


def main(argv: list[str] | None = None) -> int:
    args = parse_args(script_argv(sys.argv if argv is None else argv))
    try:
        report = run(args)
    except ScriptError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # noqa: BLE001 - engine input errors and the like: one line
        from_engine = type(e).__module__.startswith("divas_engine")
        print(f"error: {e}" if from_engine else f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    c = report["counts"]
    print(
        f"{c['accepted']} of {c['centroid_views']} centroid views fused "
        f"({c['rejected']} rejected); {c['selected']} "
        f"{'surfels' if report['kind'] == '2dgs' else 'voxels'} selected → {args.request.out} "
        f"({report['timings']['T_pipe_s']:.1f} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

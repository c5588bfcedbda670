"""DivAS on the real-capture targets, with and without the 3DGS
completion, against both peers fed the same masks.

For every target of ``tests/data/targets`` (ground truth made by rule,
:mod:`divas_engine.evaluation.real_targets`): one scripted session with the target's
hand-placed anchors and clicks (protocol ``clicks`` of
:func:`~divas_engine.evaluation.pipeline.run_session`), once with the SAM-like oracle and once
with the classic segmenter; scored at the target's test views with
:class:`~divas_engine.evaluation.metrics.ViewEvaluator` (the NOTES protocol) and
:class:`~divas_engine.evaluation.fidelity.FidelityEvaluator`. Methods (:data:`METHODS`): DivAS,
DivAS without the completion, the centre and contribution votes fed the session's accepted
masks, and the ground truth itself (the metrics' ceiling).

    python benchmarks/bench_real_captures.py [--targets biker/helmet,guitar/neck]
        [--segmenters oracle,classic] [--scale 1] [--eval-scale 1] [--seed 0]
        [--device cpu] [--json OUT.json] [--export DIR] [--breakdown]

``--export DIR`` also writes per target ``prompts.json`` and ``gt.npy`` so the same run can be
made with ``divas segment SCENE --prompts prompts.json --segmenter oracle --gt-labels gt.npy``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.evaluation.baselines import ContributionVoter, centre_vote  # noqa: E402
from divas_engine.evaluation.breakdown import completion_sources, source_breakdown  # noqa: E402
from divas_engine.evaluation.fidelity import FidelityEvaluator  # noqa: E402
from divas_engine.evaluation.metrics import EvalConfig, ViewEvaluator  # noqa: E402
from divas_engine.evaluation.pipeline import make_segmenter, run_session  # noqa: E402
from divas_engine.evaluation.real_target_defs import CAPTURES  # noqa: E402
from divas_engine.evaluation.real_targets import (  # noqa: E402
    evaluation_cameras,
    oracle_anchors,
    read_targets,
    target_scene_labels,
)
from divas_engine.io.load import load_scene  # noqa: E402
from divas_engine.render import make_renderer  # noqa: E402
from divas_engine.session import SessionConfig  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def _export(out: Path, cap: str, name: str, doc: dict, anchors) -> None:
    d = out / f"{cap}_{name}"
    d.mkdir(parents=True, exist_ok=True)
    np.save(d / "gt.npy", doc["targets"][name]["labels"])
    prompts = {
        "version": 1,
        "anchors": [
            {"camera": cam.to_dict(), "clicks": [{"xy": list(c)} for c in clicks]}
            for cam, _, _, clicks in anchors
        ],
    }
    (d / "prompts.json").write_text(json.dumps(prompts, indent=1))


METHODS = {
    "divas": "DivAS (with 3DGS completion)",
    "divas_paper": "DivAS w/o completion (paper passes)",
    "centre_vote": "(a) centre-projection vote",
    "contrib_vote": "(b) contribution vote (FlashSplat-style)",
    "truth": "the ground truth itself (the metrics' ceiling)",
}


def _breakdown_line(br: dict) -> str:
    """One line of :func:`source_breakdown`: per source TP / FP counts, FP opacity and the
    opacity-weighted IoU without that source's false Gaussians."""
    parts = [
        f"{k} tp {v['tp']} fp {v['fp']} (op {v['fp_w']:.1f}, IoU w/o {v['iou_without_fp']:.3f})"
        for k, v in br.items()
        if k != "missed"
    ]
    m = br["missed"]
    return "breakdown: " + "; ".join(parts) + f"; missed {m['fn']} (op {m['fn_w']:.1f})"


def run(args: argparse.Namespace) -> list[dict]:
    wanted = None if not args.targets else set(args.targets.split(","))
    segs = args.segmenters.split(",")
    rows = []
    for cap, c in CAPTURES.items():
        names = [t.name for t in c.targets if wanted is None or f"{cap}/{t.name}" in wanted]
        if not names:
            continue
        scene = load_scene(DATA / c.path)
        renderer = make_renderer(scene, device=args.device)
        voter = ContributionVoter(scene, args.device)
        doc = read_targets(DATA / "targets" / cap)
        for name in names:
            labels = target_scene_labels(scene, doc, name)
            anchors = oracle_anchors(scene, c.true_up, doc["targets"][name]["anchors"])
            cams = evaluation_cameras(scene, labels, c.true_up, device=args.device)
            if args.export:
                _export(args.export, cap, name, doc, anchors)
            ecfg = EvalConfig(scale=args.eval_scale)
            ev = ViewEvaluator(scene, cams, labels, config=ecfg, renderer=renderer)
            fid = FidelityEvaluator(
                scene, cams, labels, gt_masks=ev.gt_masks, scale=args.eval_scale, renderer=renderer
            )
            for seg in segs:
                t0 = time.perf_counter()
                out = run_session(
                    scene,
                    [],
                    labels,
                    anchors,
                    segmenter=make_segmenter(seg, args.seed),
                    config=SessionConfig(render_scale=args.scale, seed=args.seed),
                    device=args.device,
                    renderer=renderer,
                )
                t_session = time.perf_counter() - t0
                mviews = out.views if args.baseline_masks == "raw" else out.weighted_views
                sels = {
                    "divas": out.selection,
                    "divas_paper": out.mapped,
                    "centre_vote": centre_vote(scene, mviews, renderer=renderer).selected,
                    "contrib_vote": voter.vote(mviews).selected,
                    "truth": labels,
                }
                scores = ev.score(sels)
                fids = fid.score(sels)
                if args.save_selections:
                    args.save_selections.mkdir(parents=True, exist_ok=True)
                    np.savez_compressed(
                        args.save_selections / f"{cap}_{name}_{seg}.npz", gt=labels, **sels
                    )
                for m in sels:
                    sc, f = scores[m], fids[m]
                    row = {
                        "target": f"{cap}/{name}",
                        "segmenter": seg,
                        "method": m,
                        "gaussians": int(labels.sum()),
                        "clicks": sum(len(a[3]) for a in anchors),
                        "fused": sum(1 for _, st, _ in out.statuses if st == "fused"),
                        "test_views": len(cams),
                        "image_iou": sc.iou,
                        "pooled_iou": sc.pooled_iou,
                        "precision": sc.precision,
                        "recall": sc.recall,
                        "gaussian_iou": sc.primitives["iou"],
                        "gaussian_recall": sc.primitives["recall"],
                        "gaussian_precision": sc.primitives["precision"],
                        **f,
                        "session_s": t_session,
                        "completion": out.completion if m == "divas" else None,
                    }
                    rows.append(row)
                    print(
                        f"{row['target']:18s} {seg:7s} {m:12s} views {len(cams):2d} "
                        f"fused {row['fused']}/{row['clicks']}  image IoU {sc.iou:.3f} "
                        f"alpha {f['alpha_fidelity']:.3f}  op-IoU "
                        f"{f['opacity_weighted_iou']:.3f}  PSNR {f['psnr']:.2f} "
                        f"(vs truth {f['psnr_vs_truth']:.2f}, ceiling {f['psnr_ceiling']:.2f})  "
                        f"Gaussian IoU {row['gaussian_iou']:.3f} "
                        f"R {row['gaussian_recall']:.3f} P {row['gaussian_precision']:.3f}",
                        flush=True,
                    )
                print(f"  session {t_session:.1f} s, completion {out.completion}", flush=True)
                if args.breakdown and out.completion_masks is not None:
                    br = source_breakdown(
                        out.selection,
                        labels,
                        np.asarray(scene.opacities, np.float64),
                        completion_sources(out.mapped, **out.completion_masks),
                    )
                    rows[-len(sels)]["breakdown"] = br  # the DivAS row
                    print("  " + _breakdown_line(br), flush=True)
    return rows


def markdown(rows: list[dict]) -> str:
    """The rows as a Markdown table, one line per target × method (docs/benchmarks-history.md)."""
    out = [
        "| target | method | image IoU | alpha fidelity | opacity-w. IoU | PSNR dB (vs truth) "
        "| Gaussian IoU (R / P) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        out.append(
            f"| {r['target']} | {METHODS.get(r['method'], r['method'])} | {r['image_iou']:.3f} | "
            f"{r['alpha_fidelity']:.3f} | {r['opacity_weighted_iou']:.3f} | "
            f"{r['psnr']:.1f} ({r['psnr_vs_truth']:.1f}) | {r['gaussian_iou']:.3f} "
            f"({r['gaussian_recall']:.3f} / {r['gaussian_precision']:.3f}) |"
        )
    for m, label in METHODS.items():
        rs = [r for r in rows if r["method"] == m]
        if rs:
            mean = lambda k: float(np.mean([r[k] for r in rs]))  # noqa: E731, B023
            out.append(
                f"| **mean** | {label} | **{mean('image_iou'):.3f}** | "
                f"**{mean('alpha_fidelity'):.3f}** | **{mean('opacity_weighted_iou'):.3f}** | "
                f"**{mean('psnr'):.1f}** ({mean('psnr_vs_truth'):.1f}) | "
                f"**{mean('gaussian_iou'):.3f}** |"
            )
    return "\n".join(out)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--targets", default="", help="capture/target,… (default: all)")
    p.add_argument("--segmenters", default="oracle,classic")
    p.add_argument("--scale", type=float, default=1.0, help="session render scale (default 1)")
    p.add_argument("--eval-scale", type=float, default=1.0, help="test-view scale (default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.add_argument(
        "--baseline-masks",
        choices=("raw", "weighted"),
        default="raw",
        help="masks fed to the peers: the segmenter's (raw, default, as divas eval) or "
        "the depth-weighted ones DivAS fused",
    )
    p.add_argument("--save-selections", type=Path, default=None, help="npz per target")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument(
        "--breakdown",
        action="store_true",
        help="also split DivAS's true / false Gaussians by source (paper, contribution, fill)",
    )
    p.add_argument("--export", type=Path, default=None)
    args = p.parse_args()
    cpu = platform.processor() or platform.machine()
    print(
        f"# bench_real_captures {datetime.date.today()} {cpu} ({os.cpu_count()} CPUs), "
        f"device {args.device}, session scale {args.scale}, "
        f"test views at scale {args.eval_scale}, seed {args.seed}"
    )
    rows = run(args)
    for seg in args.segmenters.split(","):
        for m in METHODS:
            r = [x for x in rows if x["segmenter"] == seg and x["method"] == m]
            if r:
                mean = lambda k: np.mean([x[k] for x in r])  # noqa: E731, B023
                print(
                    f"mean {seg:7s} {m:12s} image IoU {mean('image_iou'):.3f}  alpha "
                    f"{mean('alpha_fidelity'):.3f}  op-IoU {mean('opacity_weighted_iou'):.3f}  "
                    f"PSNR {mean('psnr'):.2f}  Gaussian IoU {mean('gaussian_iou'):.3f} "
                    f"over {len(r)} targets"
                )
    print(markdown(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Number of clicks (NoC) and IoU after k = 1 … 10 clicks of the simulated user
(:mod:`divas_engine.evaluation.noc`: RITM/SimpleClick-style, each next click at the
deepest point of the largest error over the anchor views, positive on a miss, negative
on a spill) for each segmenter, on the synthetic suite (2DGS and 3DGS variants) and
every real-capture target, the tuning and held-out halves apart
(:mod:`divas_engine.evaluation.noc_suite`). Prints Markdown tables, the machine and the
date; writes the rows as JSON and a PNG plot of mIoU vs clicks (drawn with OpenCV).

    python benchmarks/bench_noc.py [--segmenters graph3d,oracle,classic]
        [--scenes ribs,plant,occluded,wheel,pedestal] [--kinds 2dgs,3dgs]
        [--targets all|none|guitar/stand,...] [--size 20000] [--max-clicks 10]
        [--eval-scale 0.5] [--pred-threshold T] [--half all|tuning|held-out] [--json OUT]
        [--plot OUT.png]
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

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.evaluation.noc import NocConfig  # noqa: E402
from divas_engine.evaluation.noc_suite import (  # noqa: E402
    noc_table,
    real_cases,
    run_cases,
    summary,
    synthetic_cases,
)
from divas_engine.synthetic import SCENE_NAMES  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"
COLOURS = {"graph3d": (40, 90, 220), "oracle": (60, 160, 60), "classic": (200, 120, 40)}


def plot_miou(summ: dict, path: Path, title: str, colours: dict | None = None) -> None:
    """mIoU vs clicks per segmenter, solid = tuning half, dashed = held-out (OpenCV);
    ``colours``: BGR per segmenter name (default :data:`COLOURS`)."""
    colours = COLOURS if colours is None else colours
    w, h, left, right, top, bottom = 960, 560, 80, 270, 50, 60
    img = np.full((h, w, 3), 255, np.uint8)
    pw, ph = w - left - right, h - top - bottom
    lo = 0.0
    n = max(len(s["miou"]) for s in summ.values())

    def xy(k: int, v: float) -> tuple[int, int]:
        return (
            left + int(round((k - 1) / max(n - 1, 1) * pw)),
            top + int(round((1 - (v - lo) / (1 - lo)) * ph)),
        )

    font = cv2.FONT_HERSHEY_SIMPLEX
    for g in np.linspace(lo, 1.0, 11):
        y = xy(1, g)[1]
        cv2.line(img, (left, y), (left + pw, y), (225, 225, 225), 1)
        cv2.putText(img, f"{g:.1f}", (left - 45, y + 5), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for k in range(1, n + 1):
        x = xy(k, lo)[0]
        cv2.line(img, (x, top), (x, top + ph), (235, 235, 235), 1)
        cv2.putText(img, str(k), (x - 5, top + ph + 20), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for g in (0.85, 0.90):
        y = xy(1, g)[1]
        cv2.line(img, (left, y), (left + pw, y), (150, 150, 150), 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (left + pw, top + ph), (0, 0, 0), 1)
    cv2.putText(img, "clicks", (left + pw // 2 - 25, h - 15), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "mIoU", (10, top - 15), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 30), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    ly = top + 10
    for s in summ.values():
        if s["half"] == "all":
            continue
        col = colours.get(s["segmenter"], (0, 0, 0))
        pts = [xy(k + 1, v) for k, v in enumerate(s["miou"])]
        dashed = s["half"] == "held-out"
        for a, b in zip(pts[:-1], pts[1:]):
            if dashed:
                for t0 in np.arange(0.0, 1.0, 0.25):
                    p0 = (int(a[0] + (b[0] - a[0]) * t0), int(a[1] + (b[1] - a[1]) * t0))
                    t1 = t0 + 0.14
                    p1 = (int(a[0] + (b[0] - a[0]) * t1), int(a[1] + (b[1] - a[1]) * t1))
                    cv2.line(img, p0, p1, col, 2, cv2.LINE_AA)
            else:
                cv2.line(img, a, b, col, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, col, -1, cv2.LINE_AA)
        x0 = left + pw + 15
        if dashed:
            cv2.line(img, (x0, ly), (x0 + 10, ly), col, 2)
            cv2.line(img, (x0 + 16, ly), (x0 + 26, ly), col, 2)
        else:
            cv2.line(img, (x0, ly), (x0 + 26, ly), col, 2)
        label = f"{s['segmenter']}, {s['half']}"
        cv2.putText(img, label, (x0 + 32, ly + 5), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        ly += 24
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--segmenters", default="graph3d,oracle,classic")
    p.add_argument("--scenes", default=",".join(SCENE_NAMES))
    p.add_argument("--kinds", default="2dgs,3dgs")
    p.add_argument("--targets", default="all", help="all, none, or capture/target,…")
    p.add_argument("--size", type=int, default=20_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-clicks", type=int, default=10)
    p.add_argument("--eval-scale", type=float, default=0.5)
    p.add_argument(
        "--pred-threshold",
        type=float,
        default=None,
        help="the prediction's mask threshold on every case (default 0.5, as the truth's; "
        "0.1: NOTES' 2DGS protocol)",
    )
    p.add_argument("--half", choices=("all", "tuning", "held-out"), default="all")
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--plot", type=Path, default=None)
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    segs = [s for s in args.segmenters.split(",") if s]
    cases = []
    if args.scenes:
        cases += synthetic_cases(
            [s for s in args.scenes.split(",") if s], [k for k in args.kinds.split(",") if k]
        )
    if args.targets != "none":
        cases += real_cases(None if args.targets == "all" else args.targets.split(","))
    if args.half != "all":
        cases = [c for c in cases if c.half == args.half]
    cfg = NocConfig(
        max_clicks=args.max_clicks, eval_scale=args.eval_scale, pred_threshold=args.pred_threshold
    )
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    t_all = time.perf_counter()
    rows = run_cases(
        cases,
        segs,
        size=args.size,
        seed=args.seed,
        config=cfg,
        data_dir=DATA,
        device=args.device,
        log=say,
    )
    wall = time.perf_counter() - t_all
    summ = summary(rows, cfg.thresholds)
    print(noc_table(rows, cfg.thresholds))
    print(
        "\n| segmenter | half | cases | "
        + " | ".join(f"mIoU@{k}" for k in (1, 3, 5, 10) if k <= cfg.max_clicks)
        + " | NoC@85 | NoC@90 | NoF@90 |"
    )
    print("|---|---|---:|" + "---:|" * (len([k for k in (1, 3, 5, 10) if k <= cfg.max_clicks]) + 3))
    for s in summ.values():
        cells = [f"{s['miou'][k - 1]:.3f}" for k in (1, 3, 5, 10) if k <= cfg.max_clicks]
        print(
            f"| {s['segmenter']} | {s['half']} | {s['cases']} | "
            + " | ".join(cells)
            + f" | {s['noc']['0.85']:.2f} | {s['noc']['0.9']:.2f} | {s['nof']['0.9']} |"
        )
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"\n{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"{stamp}, load {load:.1f}, {wall:.0f} s; size {args.size}, eval scale "
        f"{args.eval_scale}, seed {args.seed}, prediction threshold "
        f"{0.5 if args.pred_threshold is None else args.pred_threshold}"
    )
    if args.json is not None:
        args.json.write_text(
            json.dumps({"rows": rows, "summary": summ, "date": stamp, "wall_s": wall}, indent=1)
        )
    if args.plot is not None:
        plot_miou(summ, args.plot, f"mIoU vs clicks, simulated user ({stamp})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

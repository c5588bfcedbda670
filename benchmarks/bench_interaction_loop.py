"""What the Blender interaction loop adds, on real captures: anchor resolution
vs click / accept latency, the cost of an undo or redo of any step (session history)
next to the accept it undoes, and the manual selection tools on the capture's points.

For each capture target (the hand-placed anchors of ``tests/data/targets``): a session
with the classic segmenter at each anchor resolution (long side of the anchor image; 0
= the anchor camera × ``--scale``, 320×240 by default), one click per anchor, each view
accepted; every step recorded in the history, then undone and redone one by one.
Medians per step. Selection tools: ``project_to_region`` + box / 24-gon lasso / circle
on every point, and one grow / shrink step with the automatic radius.

    python benchmarks/bench_interaction_loop.py [--targets guitar/guitar,biker/helmet]
        [--resolutions 0,640,800] [--scale 0.5] [--device cpu]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.evaluation.real_target_defs import CAPTURES  # noqa: E402
from divas_engine.evaluation.real_targets import oracle_anchors, read_targets  # noqa: E402
from divas_engine.io.load import load_scene  # noqa: E402
from divas_engine.segment import ClassicSegmenter  # noqa: E402
from divas_engine.selection_tools import (  # noqa: E402
    RegionView,
    grow,
    in_box,
    in_circle,
    in_lasso,
    neighbour_radius,
    project_to_region,
    shrink,
)
from divas_engine.session import Session, SessionConfig  # noqa: E402
from divas_engine.viewport import region_matrices  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def _ms(xs) -> str:
    return f"{1e3 * float(np.median(xs)):.0f}" if len(xs) else "—"


def loop_row(scene, anchors, long_side: int, scale: float, device: str) -> str:
    cfg = SessionConfig(render_scale=scale, anchor_long_side=long_side)
    t0 = time.perf_counter()
    s = Session.open(scene, [], cfg, ClassicSegmenter(), device, anchors=[a[:3] for a in anchors])
    t_open = time.perf_counter() - t0
    h = s.history
    click, accept, record = [], [], []
    for i, (cam, _, _, clicks) in enumerate(anchors):
        a = s.anchors[i]
        xy = np.asarray(clicks[0], float) * (a.camera.width / cam.width)
        t = time.perf_counter()
        try:
            v = s.click(i, xy)
            s.prompt(v)
        except Exception:  # noqa: BLE001 - a click that misses at this resolution
            continue
        click.append(time.perf_counter() - t)
        t = time.perf_counter()
        h.record("click")
        record.append(time.perf_counter() - t)
        t = time.perf_counter()
        s.accept(v)
        accept.append(time.perf_counter() - t)
        h.record("accept")
    undo: dict[str, list] = {"click": [], "accept": []}
    redo: dict[str, list] = {"click": [], "accept": []}
    while h.can_undo:
        what = h.current.what
        t = time.perf_counter()
        h.undo()
        undo[what].append(time.perf_counter() - t)
    while h.can_redo:
        what = h.redo_name
        t = time.perf_counter()
        h.redo()
        redo[what].append(time.perf_counter() - t)
    size = f"{s.anchors[0].camera.width}×{s.anchors[0].camera.height}"
    s.close()
    return (
        f"| {size} | {t_open:.1f} | {len(accept)} | {_ms(click)} | {_ms(accept)} | "
        f"{_ms(record)} | {_ms(undo['click'])} / {_ms(undo['accept'])} | "
        f"{_ms(redo['click'])} / {_ms(redo['accept'])} |"
    )


def tools_row(name: str, points: np.ndarray, cam) -> str:
    vm, wm = region_matrices(cam)
    view = RegionView(wm @ vm, cam.width, cam.height)
    w, h = cam.width, cam.height
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    lasso = np.c_[w / 2 + 0.3 * w * np.cos(ang), h / 2 + 0.3 * h * np.sin(ang)]
    t = time.perf_counter()
    xy, front = project_to_region(points, view)
    t_proj = time.perf_counter() - t
    t = time.perf_counter()
    box = in_box(xy, front, (0.3 * w, 0.3 * h, 0.7 * w, 0.7 * h))
    t_box = time.perf_counter() - t
    t = time.perf_counter()
    las = in_lasso(xy, front, lasso)
    t_lasso = time.perf_counter() - t
    t = time.perf_counter()
    in_circle(xy, front, (w / 2, h / 2), 40)
    t_circle = time.perf_counter() - t
    t = time.perf_counter()
    r = neighbour_radius(points)
    t_radius = time.perf_counter() - t
    t = time.perf_counter()
    g = grow(points, las, r)
    t_grow = time.perf_counter() - t
    t = time.perf_counter()
    shrink(points, g, r)
    t_shrink = time.perf_counter() - t
    return (
        f"| {name} | {len(points):,} | {box.sum():,} / {las.sum():,} | "
        + " | ".join(
            f"{1e3 * x:.0f}" for x in (t_proj, t_box, t_lasso, t_circle, t_radius, t_grow, t_shrink)
        )
        + " |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="guitar/guitar,biker/helmet")
    ap.add_argument("--resolutions", default="0,640,800")
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    print(
        f"# Interaction loop — {platform.machine()}, {datetime.date.today()}, "
        f"classic segmenter, render scale {args.scale}, device {args.device}\n"
    )
    tools = []
    for spec in args.targets.split(","):
        cap, target = spec.split("/")
        c = CAPTURES[cap]
        scene = load_scene(DATA / c.path)
        doc = read_targets(DATA / "targets" / cap)
        anchors = oracle_anchors(scene, c.true_up, doc["targets"][target]["anchors"])
        print(f"## {cap}/{target}: {len(scene):,} splats, {len(anchors)} anchors\n")
        print(
            "| anchor image | open s | views | click+preview ms | accept ms | "
            "record ms | undo click / accept ms | redo click / accept ms |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for res in (int(r) for r in args.resolutions.split(",")):
            print(loop_row(scene, anchors, res, args.scale, args.device))
        print()
        tools.append(tools_row(cap, scene.means, anchors[0][0]))
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(1_000_000, 3)) * [1.0, 1.0, 0.3]
    cam = anchors[0][0].with_pose(np.eye(4))
    cam = cam.with_pose(
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -4.0], [0, 0, 0, 1]], float)
    )
    tools.append(tools_row("synthetic", cloud, cam))
    print("## Selection tools (ms)\n")
    print(
        "| points | N | in box / lasso | project | box | lasso | circle | radius | grow | shrink |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(tools))


if __name__ == "__main__":
    main()

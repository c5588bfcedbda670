"""How much the weight-free default (graph3d) depends on exactly where the user clicks, on
the real-capture targets.

For every target of ``tests/data/targets`` (the hand-placed anchors and clicks of
``bench_real_captures.py``): ``--draws`` sessions of the ``clicks`` protocol (every click
spawns its centroid view, then every view is accepted, as ``divas segment``), the first
with the target's own clicks and the others with every click moved by an offset drawn
uniformly in ±``--radius`` full-camera pixels (a click that then lands off every surface
is moved halfway back, then onto the original pixel: the user clicks again, nearer).
Printed per target: the views fused per draw and the Gaussian IoU against the rule-made
truth (mean, min, and that of the unmoved clicks). An accept that flips from fused to
rejected between draws is a score that hangs on millimetres of the click's 3D point.

    python benchmarks/bench_click_robustness.py [--draws 8] [--radius 3] [--scale 1]
        [--targets guitar/guitar,…] [--neck-min-voxels N] [--seed 0]

``--scale``: the session's render scale (0.5: 320 × 240 anchors, a prompts-file start's
default in the add-on). ``--neck-min-voxels``: graph3d's narrowness guard (default: the
config's).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.errors import DivasInputError  # noqa: E402
from divas_engine.evaluation.real_target_defs import CAPTURES  # noqa: E402
from divas_engine.evaluation.real_targets import (  # noqa: E402
    oracle_anchors,
    read_targets,
    target_scene_labels,
)
from divas_engine.io.load import load_scene  # noqa: E402
from divas_engine.kinds import ViewStatus  # noqa: E402
from divas_engine.segment.graph3d import Graph3DConfig, Graph3DSegmenter  # noqa: E402
from divas_engine.session import Session, SessionConfig  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def one_session(scene, anchors, offsets, config: SessionConfig, g3d: Graph3DConfig):
    """``(fused, spawned, selection)`` of the clicks protocol with every click of
    ``anchors`` moved by its row of ``offsets`` (full-camera pixels)."""
    s = Session.open(scene, [], config, Graph3DSegmenter(g3d), "cpu")
    try:
        views, k = [], 0
        for cam, source, index, clicks in anchors:
            a = s.add_anchor(cam, source, index)
            for xy in clicks:
                off = offsets[k]
                k += 1
                for f in (1.0, 0.5, 0.0):  # off every surface: the user clicks nearer
                    p = (xy[0] + f * off[0], xy[1] + f * off[1])
                    try:
                        views.append(s.click(a.index, a.full_camera.pixels_to(a.camera, p)))
                        break
                    except DivasInputError:
                        if f == 0.0:
                            raise
        for v in views:
            s.accept(v)
        fused = sum(1 for v in views if s.view(v.id).status == ViewStatus.FUSED)
        return fused, len(views), s.selection.copy()
    finally:
        s.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--radius", type=float, default=3.0)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--targets", default="")
    ap.add_argument("--neck-min-voxels", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    wanted = set(filter(None, args.targets.split(",")))
    g3d = Graph3DConfig()
    if args.neck_min_voxels is not None:
        g3d = replace(g3d, neck_min_voxels=args.neck_min_voxels)
    config = SessionConfig(render_scale=args.scale, seed=args.seed)
    print(
        f"# bench_click_robustness {datetime.date.today()} {platform.machine()} "
        f"({os.cpu_count()} CPUs), scale {args.scale}, ±{args.radius} px, "
        f"{args.draws} draws, graph3d neck_min_voxels {g3d.neck_min_voxels}"
    )
    print("| target | views fused per draw | Gaussian IoU mean | min | unmoved clicks |")
    print("|---|---|---:|---:|---:|")
    t0 = time.perf_counter()
    for cap, c in CAPTURES.items():
        names = [t.name for t in c.targets if not wanted or f"{cap}/{t.name}" in wanted]
        if not names:
            continue
        scene = load_scene(DATA / c.path)
        doc = read_targets(DATA / "targets" / cap)
        for name in names:
            truth = target_scene_labels(scene, doc, name) > 0.5
            anchors = oracle_anchors(scene, c.true_up, doc["targets"][name]["anchors"])
            n_clicks = sum(len(a[3]) for a in anchors)
            rng = np.random.default_rng(args.seed)
            fused, ious = [], []
            for d in range(args.draws):
                offsets = np.zeros((n_clicks, 2))
                if d > 0:
                    offsets = rng.uniform(-args.radius, args.radius, (n_clicks, 2))
                ok, n, sel = one_session(scene, anchors, offsets, config, g3d)
                fused.append(f"{ok}/{n}")
                ious.append(float((sel & truth).sum() / max((sel | truth).sum(), 1)))
            print(
                f"| {cap}/{name} | {' '.join(fused)} | {np.mean(ious):.3f} | "
                f"{np.min(ious):.3f} | {ious[0]:.3f} |",
                flush=True,
            )
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

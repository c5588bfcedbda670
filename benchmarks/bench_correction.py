"""Latency of a correction: one click as a 3D constraint — its back-projection
and surface patch, the views it re-segments, their re-fusion and the mapping.

On one synthetic scene (default: the 1M-surfel ``plant``) a session with the oracle or
``graph3d`` fuses the first ``--views`` demo-prompt views, then makes the simulated user's next
clicks on its anchors (``tests/click_user.py``'s rule), then negative clicks on the deepest
spill (or on the selection, where every fused view showing the spot disagrees), then
(``--unseen``) a negative click on a selected spot that no fused view sees, which fuses
the click's own view. Each correction
is timed ``--repeats`` times (undone exactly between repeats) as wall and CPU seconds, with its
stages and changed views, beside one full render of the same anchor; the load average is
printed with the figures.

    python benchmarks/bench_correction.py [--size 1000000] [--scene plant]
        [--segmenter oracle] [--views 4] [--clicks 2] [--negatives 2] [--unseen 1]
        [--repeats 3]
        [--device cpu]
    python benchmarks/bench_correction.py --target biker/helmet --segmenter oracle --clicks 8

The second form: the simulated user on a real target of ``tests/data``, the image IoU at its
evaluation cameras after each click, with the corrections off (the paper's loop) and on.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_session import scene_files, sync  # noqa: E402

from divas_engine.io.cameras import load_cameras  # noqa: E402
from divas_engine.io.load import load_scene  # noqa: E402
from divas_engine.session.prompts import load_prompts  # noqa: E402


def _deepest(session, labels: np.ndarray, kinds: tuple[str, ...]):
    """The deepest pixel (distance transform) over the rendered anchors of the first
    non-empty set of ``kinds``: ``"missed"`` (truth, not selected), ``"spill"``
    (selected, not truth), ``"selected"``; ``(anchor, xy, positive, kind)`` or None.
    ``("missed", "spill")`` together is the simulated user's next click."""
    best = None
    sel = session.selection.astype(np.float32)
    for a in session.anchors:
        if not a.rendered:
            continue
        shape = (a.camera.height, a.camera.width)
        t = session.renderer.render_values(a.camera, labels).reshape(shape) >= 0.5
        p = session.renderer.render_values(a.camera, sel).reshape(shape) >= 0.5
        sets = {"missed": t & ~p, "spill": p & ~t, "selected": p}
        for rank, kind in enumerate(kinds):
            err = sets[kind]
            if err.any():
                d = ndimage.distance_transform_edt(np.pad(err, 1))[1:-1, 1:-1]
                i = int(np.argmax(d))
                tie = 0 if len(kinds) == 2 else rank  # the user's click: the deepest error
                key = (tie, -float(d.flat[i]), rank, a.index)
                if best is None or key < best[0]:
                    y, x = divmod(i, shape[1])
                    best = (key, (a.index, (x + 0.5, y + 0.5), kind == "missed", kind))
    return None if best is None else best[1]


def _unseen(session, tries: int = 400):
    """A selected pixel of a rendered anchor (the deepest first) whose surface point no
    view of the object sees: ``(anchor, xy, False, "unseen")`` — a negative click there
    fuses the click's own view (``session/negative_views.py``) — or None."""
    from divas_engine.session.negative_views import seen_by_a_view

    sel = session.selection.astype(np.float32)
    for a in session.anchors:
        if not a.rendered:
            continue
        cam, b = a.camera, a.buffers
        p = session.renderer.render_values(cam, sel).reshape(cam.height, cam.width) >= 0.5
        p &= np.asarray(b.D_med) > 0
        if not p.any():
            continue
        d = ndimage.distance_transform_edt(np.pad(p, 1))[1:-1, 1:-1]
        for i in np.argsort(-d, axis=None)[:tries]:
            y, x = divmod(int(i), cam.width)
            z = float(b.D_med[y, x])
            point = cam.unproject(np.array([[x + 0.5, y + 0.5]]), np.array([z]))[0]
            if z > 0 and not seen_by_a_view(session, point):
                return a.index, (x + 0.5, y + 0.5), False, "unseen"
    return None


def run(args) -> list[dict]:
    from divas_engine.segment.graph3d import Graph3DSegmenter
    from divas_engine.segment.oracle import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    folder = scene_files(args.scene, args.size)
    scene = load_scene(folder / "scene.ply")
    cameras = load_cameras(folder / "cameras.json")
    labels = np.load(folder / "labels.npy").astype(np.float32)
    prompts = load_prompts(folder / "prompts.json")
    by_name = {c.name: c for c in cameras}
    oracle = args.segmenter == "oracle"
    seg = OracleSegmenter() if oracle else Graph3DSegmenter()
    s = Session.open(scene, cameras, SessionConfig(), seg, args.device,
                     gt_values=labels if oracle else None, render_anchors=False)  # fmt: skip
    s.wait_warm_up()
    n = 0
    for ap in prompts.anchors:
        a = s.add_anchor(by_name[ap.value], "training", 0)
        for c in ap.clicks:
            if n >= args.views:
                break
            xy = a.full_camera.pixels_to(a.camera, c.xy)
            v = s.click(a.index, xy)
            s.accept(v)
            n += 1
        if n >= args.views:
            break
    h = s.history
    rows = []
    plan = [("missed", "spill")] * args.clicks + [("spill", "selected")] * args.negatives
    plan += [None] * args.unseen
    for k, kinds in enumerate(plan):
        click = _deepest(s, labels, kinds) if kinds else _unseen(s)
        if click is None:
            continue
        ai, xy, positive, kind = click
        step = h.record(f"before correction {k}")
        walls, cpus, stages = [], [], []
        for r in range(args.repeats):
            if r:
                h.record(f"repeat {r}")
                h.goto(step.id)  # exact: the fusion reconciled slot by slot
            sync(args.device)
            t, c = time.perf_counter(), time.process_time()
            res = s.click(ai, xy, positive)
            sync(args.device)
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
            stages.append(s.last_correction.timings)
            if positive:  # the user accepts the view a positive click spawned
                s.accept(res)
        h.record(f"correction {k}")
        corr = s.last_correction
        a = s.anchors[ai]
        t, c = time.perf_counter(), time.process_time()
        s.renderer.render(a.camera, attached=False)
        sync(args.device)
        render_s, render_cpu = time.perf_counter() - t, time.process_time() - c
        rows.append(
            {
                "click": f"{'+' if positive else '-'} {kind}, anchor {ai}",
                "views": corr.views_changed,
                "fused": len(s.state.live_views()),
                "patch": len(corr.correction.patch),
                "delta": f"+{len(corr.added)} / -{len(corr.removed)}",
                "wall_s": float(np.median(walls)),
                "cpu_s": float(np.median(cpus)),
                **{
                    k: float(np.median([st.get(k, 0.0) for st in stages]))
                    for k in ("segmenter_s", "kernel_s", "mapping_s", "update_s")
                },  # fmt: skip
                "render_s": render_s,
                "render_cpu_s": render_cpu,
            }
        )
    s.close()
    return rows


def target_run(args) -> dict[str, list[str]]:
    """Per click, ``"± IoU"`` of the simulated user on a real target, with the
    corrections on and off (off: the paper's loop, negative clicks prompt their anchor's
    later views only)."""
    from divas_engine.evaluation.pipeline import make_segmenter
    from divas_engine.evaluation.real_target_defs import CAPTURES
    from divas_engine.evaluation.real_targets import (
        evaluation_cameras,
        oracle_anchors,
        read_targets,
        target_scene_labels,
    )
    from divas_engine.session import CorrectionConfig, Session, SessionConfig

    data = Path(__file__).resolve().parents[1] / "tests" / "data"
    cap_name, name = args.target.split("/")
    cap = CAPTURES[cap_name]
    scene = load_scene(data / cap.path)
    doc = read_targets(data / "targets" / cap_name)
    lab = target_scene_labels(scene, doc, name)
    gt = lab.astype(np.float32)
    anchors = oracle_anchors(scene, cap.true_up, doc["targets"][name]["anchors"])
    tests = evaluation_cameras(scene, lab, cap.true_up, device=args.device)
    out = {}
    for on in (False, True):
        cfg = SessionConfig(corrections=CorrectionConfig(enabled=on))
        s = Session.open(scene, [], cfg, make_segmenter(args.segmenter), args.device,
                         anchors=[(c, src, i) for c, src, i, _ in anchors], gt_values=gt,
                         render_anchors=False)  # fmt: skip
        for a in s.anchors:
            s.render(a)
        col = []
        for _ in range(args.clicks):
            click = _deepest(s, gt, ("missed", "spill"))
            if click is None:
                col.append("done")
                continue
            ai, xy, positive, _ = click
            try:
                res = s.click(ai, xy, positive)
                if positive:
                    s.accept(res)
            except Exception as e:  # noqa: BLE001 - a click on no surface is a spent click
                print(f"# click refused: {e}")
            col.append(f"{'+' if positive else '-'} {_iou(s, tests, gt):.3f}")
        out["on" if on else "off"] = col
        s.close()
    return out


def _iou(session, cameras, gt: np.ndarray) -> float:
    sel = session.selection.astype(np.float32)
    ious = []
    for cam in cameras:
        t = session.renderer.render_values(cam, gt).reshape(cam.height, cam.width) >= 0.5
        p = session.renderer.render_values(cam, sel).reshape(cam.height, cam.width) >= 0.5
        ious.append((t & p).sum() / max(1, (t | p).sum()))
    return float(np.mean(ious))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1_000_000)
    ap.add_argument("--scene", default="plant")
    ap.add_argument("--segmenter", default="oracle", choices=("oracle", "graph3d"))
    ap.add_argument("--views", type=int, default=4, help="views fused before the corrections")
    ap.add_argument("--clicks", type=int, default=2, help="simulated user's clicks timed")
    ap.add_argument(
        "--negatives",
        type=int,
        default=2,
        help="then negative clicks on the deepest spill (else on the selection itself)",
    )
    ap.add_argument(
        "--unseen",
        type=int,
        default=1,
        help="then negative clicks on a selected spot no fused view sees (the session "
        "fuses the click's own view)",
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--target",
        default=None,
        help="a real target (e.g. biker/helmet): IoU per click of the simulated user at "
        "its evaluation cameras, corrections off and on (--clicks clicks)",
    )
    args = ap.parse_args()
    load0 = os.getloadavg()
    if args.target:
        cols = target_run(args)
        load1 = os.getloadavg()[0]
        print(f"# {args.target}, {args.segmenter}: IoU at its evaluation cameras after each "
              f"click; load average {load0[0]:.1f} before / {load1:.1f} after")  # fmt: skip
        print("| click | corrections off | corrections on |\n|---:|---|---|")
        for k, (a, b) in enumerate(zip(cols["off"], cols["on"]), 1):
            print(f"| {k} | {a} | {b} |")
        return
    rows = run(args)
    load1 = os.getloadavg()
    print(f"# bench_correction: {args.scene} {args.size:,} surfels, {args.segmenter}, "
          f"{args.views} views fused, device {args.device}")  # fmt: skip
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{load0[0]:.1f} before / {load1[0]:.1f} after; medians of {args.repeats}")  # fmt: skip
    print(
        "# correction = the click's constraint: patch, views re-segmented, re-fusion, "
        "mapping (a positive click's whole s also plans and renders its new view)"
    )
    print(
        "| click | views changed | fused views | patch | selection delta | correction s | "
        "segmenter s | fusion s | mapping s | whole click s (CPU s) | "
        "full render of the anchor s (CPU s) | correction / render |"
    )
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['click']} | {r['views']} | {r['fused']} | {r['patch']} | {r['delta']} | "
              f"{r['update_s']:.3f} | {r['segmenter_s']:.3f} | {r['kernel_s']:.3f} | "
              f"{r['mapping_s']:.3f} | {r['wall_s']:.3f} ({r['cpu_s']:.3f}) | "
              f"{r['render_s']:.3f} ({r['render_cpu_s']:.3f}) | "
              f"{r['update_s'] / r['render_s']:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()

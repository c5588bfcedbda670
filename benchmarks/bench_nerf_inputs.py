"""The synthetic NeRF suite through every NeRF input, and the NeRF figures of the add-on.

    python benchmarks/bench_nerf_inputs.py [--seeds 0,1] [--size 20000] [--grid 128]
        [--inputs npz,ingp_net,ingp_grid,vdb] [--scale 0.5] [--segmenter oracle|classic]
        [--shade auto|on|off] [--no-suite] [--blender] [--blender-side 256]

Suite: the ``ribs`` NeRF grid of ``divas eval`` written as each input (``.npz``, instant-ngp
snapshots with and without its network, ``.vdb``), loaded back and segmented by the suite's
protocol; IoU on the input's own lattice and on the source lattice, render time per view,
click → fused view. ``--blender``: Import › NeRF of a ``--blender-side``³ grid as a Volume
and as points. One line per measure, then a JSON summary. Protocol: docs/design-notes.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

INPUTS = ("npz", "ingp_net", "ingp_grid", "vdb")
#: also accepted by --inputs: the network snapshot with its grid marched (network colour)
EXTRA_INPUTS = ("ingp_net_gridviews",)


def _write_input(kind: str, sc, d: Path) -> Path:
    from divas_engine.io.density_grid import write_density_grid
    from divas_engine.io.instant_ngp import write_ngp_document
    from divas_engine.io.openvdb_grid import write_vdb
    from divas_engine.synthetic.ngp_snapshot import snapshot_of_grid

    if kind == "npz":
        p = d / "ribs.npz"
        write_density_grid(p, sc.grid)
    elif kind in ("ingp_net", "ingp_net_gridviews"):
        p = d / "ribs_net.ingp"
        write_ngp_document(p, snapshot_of_grid(sc.grid, sc.cameras, network=True), True)
    elif kind == "ingp_grid":
        p = d / "ribs_grid.ingp"
        write_ngp_document(p, snapshot_of_grid(sc.grid, sc.cameras, network=False), True)
    elif kind == "vdb":
        p = write_vdb(d / "ribs.vdb", sc.grid)
    else:
        raise ValueError(kind)
    return p


def _carry(src_grid, values: np.ndarray, dst_grid) -> np.ndarray:
    """``values`` on ``src_grid``'s lattice sampled (nearest) at ``dst_grid``'s cells."""
    from divas_engine.synthetic.ngp_snapshot import sample_grid

    idx = np.argwhere(np.ones(dst_grid.density.shape, bool))[:, ::-1]
    c = dst_grid.aabb[0] + (idx + 0.5) * dst_grid.voxel_size
    inside = np.all((c >= src_grid.aabb[0]) & (c <= src_grid.aabb[1]), 1)
    v = sample_grid(src_grid, c, values.astype(np.float32), order=0) * inside
    return v.reshape(dst_grid.density.shape) > 0.5


def _carry_labels(src_grid, labels: np.ndarray, dst_grid) -> np.ndarray:
    """Ground truth on ``dst_grid``'s lattice: a dense cell is the object's when the
    density-weighted label sampled at its centre, ``(σ·L)~ / σ~``, is at least ½."""
    from divas_engine.synthetic.ngp_snapshot import sample_grid

    shape = dst_grid.density.shape
    idx = np.argwhere(np.ones(shape, bool))[:, ::-1]
    centres = dst_grid.aabb[0] + (idx + 0.5) * dst_grid.voxel_size
    num = sample_grid(src_grid, centres, src_grid.density * labels).reshape(shape)
    den = sample_grid(src_grid, centres, src_grid.density).reshape(shape)
    return (num >= 0.5 * den) & (den > 0) & (dst_grid.density > 0)


def _own_view_iou(grid, sel, cams, gt_masks) -> float:
    """Mean IoU of the segmented grid rendered alone (density zeroed outside the selection,
    on the loaded lattice: what the masked export and the segmented Volume hold; opacity
    ≥ ½, NOTES "Evaluation") against the true object's masks from the source grid."""
    from divas_engine.evaluation.metrics import predicted_masks

    pred = predicted_masks(grid, cams, {"s": sel})["s"]
    ious = []
    for p, gt in zip(pred, gt_masks):
        union = int((p | gt).sum())
        ious.append(int((p & gt).sum()) / union if union else 1.0)
    return float(np.mean(ious))


def _alpha_fidelity(grid, cams, labels, sel, gt_masks) -> float:
    from divas_engine.render import make_renderer

    r = make_renderer(grid)
    vals = np.stack([labels, labels & sel], -1).astype(np.float32)
    num = den = 0.0
    for cam, sil in zip(cams, gt_masks):
        img = r.render_values(cam, vals)[np.asarray(sil, bool)].astype(np.float64)
        den += float(img[:, 0].sum())
        num += float(img[:, 1].sum())
    return num / den if den > 0 else 1.0


def _click_to_fused(grid, sc, labels, renderer, cfg) -> float:
    from divas_engine.evaluation.pipeline import make_segmenter
    from divas_engine.session import Session, anchor_plan

    items = list(anchor_plan(grid, list(sc.cameras), cfg).anchors)
    s = Session.open(
        grid,
        list(sc.cameras),
        cfg,
        make_segmenter("oracle", 0),
        "cpu",
        anchors=items,
        gt_values=labels.astype(np.float32),
        renderer=renderer,
    )
    iz, iy, ix = np.nonzero(labels & (grid.density > 0))
    target = np.median(grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * grid.voxel_size, 0)
    for i, a in enumerate(s.anchors):
        uv, z = a.camera.project(target[None])
        if z[0] > 0 and 0 <= uv[0, 0] < a.camera.width and 0 <= uv[0, 1] < a.camera.height:
            t = time.perf_counter()
            v = s.click(i, (float(uv[0, 0]), float(uv[0, 1])))
            s.accept(v)
            s.sync()
            return time.perf_counter() - t
    return float("nan")


def suite(
    seeds, size, grid_res, inputs, say, render_scale: float, segmenter="oracle", shade=None
) -> list[dict]:
    from divas_engine import load_scene
    from divas_engine.evaluation.metrics import ViewEvaluator, ground_truth_masks
    from divas_engine.evaluation.pipeline import (
        CachingRenderer,
        make_segmenter,
        run_session,
        variant_config,
    )
    from divas_engine.evaluation.scripted_user import ScriptedUser
    from divas_engine.evaluation.suite import SuiteConfig
    from divas_engine.render import make_renderer
    from divas_engine.synthetic import generate_scene

    cfg = SuiteConfig()
    cfg = replace(cfg, session=replace(cfg.session, render_scale=render_scale))
    rows = []
    for seed in seeds:
        sc = generate_scene("ribs", size=size, seed=seed, grid_resolution=grid_res)
        ev = ViewEvaluator(sc.grid, sc.test_cameras, sc.grid_labels, config=cfg.eval)
        own_cams = [c.scaled(render_scale) for c in sc.test_cameras]
        own_gt = ground_truth_masks(sc.grid, own_cams, sc.grid_labels, config=cfg.eval)
        with tempfile.TemporaryDirectory() as tmp:
            for kind in inputs:
                t = time.perf_counter()
                path = _write_input(kind, sc, Path(tmp))
                t_write = time.perf_counter() - t
                t = time.perf_counter()
                g = load_scene(path)
                t_load = time.perf_counter() - t
                labels = _carry_labels(sc.grid, sc.grid_labels, g)
                rcfg = replace(cfg.session.render, shade_grid=shade)
                if kind in ("ingp_net", "ingp_net_gridviews"):  # not by device
                    rcfg = replace(rcfg, nerf_network=kind == "ingp_net")
                base = make_renderer(g, device="cpu", config=rcfg)
                renderer = CachingRenderer(base)
                cam = sc.test_cameras[0]
                base.render(cam)
                t = time.perf_counter()
                base.render(cam)
                t_view = time.perf_counter() - t
                session_cfg = replace(variant_config("full", cfg.session), render=rcfg)
                t_click = _click_to_fused(g, sc, labels, base, session_cfg)
                t = time.perf_counter()
                out = run_session(
                    g,
                    sc.cameras,
                    labels,
                    segmenter=make_segmenter(segmenter, seed),
                    config=session_cfg,
                    device="cpu",
                    renderer=renderer,
                    user=ScriptedUser(labels, cfg.user),
                )
                t_session = time.perf_counter() - t
                np.save(Path(tempfile.gettempdir()) / f"nerf_sel_{kind}_{seed}.npy", out.selection)
                sel = _carry(g, out.selection, sc.grid)
                score = ev.score({kind: sel})[kind]
                own = _own_view_iou(g, out.selection, own_cams, own_gt)
                fid = _alpha_fidelity(sc.grid, sc.test_cameras, sc.grid_labels, sel, ev.gt_masks)
                fused = sum(1 for _, st, _ in out.statuses if st == "fused")
                row = {
                    "seed": seed,
                    "input": kind,
                    "segmenter": segmenter,
                    "shade_grid": shade,
                    "image_iou_own_lattice": round(own, 4),
                    "image_iou_source_lattice": round(score.iou, 4),
                    "alpha_fidelity": round(fid, 4),
                    "render_view_s": round(t_view, 3),
                    "view": f"{cam.width}x{cam.height}",
                    "click_to_fused_s": round(t_click, 2),
                    "session_s": round(t_session, 1),
                    "views_fused": f"{fused}/{len(out.statuses)}",
                    "lattice": list(g.density.shape),
                    "write_s": round(t_write, 2),
                    "load_s": round(t_load, 2),
                    "file_mb": round(path.stat().st_size / 1e6, 2),
                }
                say(json.dumps(row))
                rows.append(row)
    return rows


def blender_import(side: int, say) -> dict:
    import bpy

    addon_utils = __import__("addon_utils")  # after bpy, which puts it on the path
    addon_utils.enable("blender_addon", default_set=True)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from scenes import density_grid

    from divas_engine.io.density_grid import write_density_grid

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        g = density_grid(side, seed=0)
        g.rgb = None  # 256³ RGB as float32 is over the .npz reader's default 256 MB budget
        p = Path(tmp) / f"grid{side}.npz"
        write_density_grid(p, g)
        for mode in ("VOLUME", "POINTS"):
            bpy.ops.wm.read_homefile(app_template="")
            t = time.perf_counter()
            assert bpy.ops.divas.import_density_grid(filepath=str(p), display_as=mode) == {
                "FINISHED"
            }
            dt = time.perf_counter() - t
            obj = bpy.context.active_object
            out[f"import_{mode.lower()}_s"] = round(dt, 2)
            out["voxels"] = len(obj.data.points)
        say(json.dumps({"blender_import": side, **out}))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--size", type=int, default=20000)
    p.add_argument("--grid", type=int, default=128)
    p.add_argument("--inputs", default=",".join(INPUTS))
    p.add_argument("--scale", type=float, default=0.5, help="session render scale (0.5)")
    p.add_argument("--segmenter", default="oracle", help="oracle (default) or classic")
    p.add_argument(
        "--shade", choices=("auto", "on", "off"), default="auto", help="RenderConfig.shade_grid"
    )
    p.add_argument("--no-suite", action="store_true")
    p.add_argument("--blender", action="store_true")
    p.add_argument("--blender-side", type=int, default=256)
    a = p.parse_args(argv)
    print("uptime:", os.popen("uptime").read().strip(), flush=True)
    say = lambda s: print(s, flush=True)  # noqa: E731
    summary: dict = {}
    if not a.no_suite:
        seeds = [int(s) for s in a.seeds.split(",")]
        shade = {"auto": None, "on": True, "off": False}[a.shade]
        inputs = a.inputs.split(",")
        summary["suite"] = suite(seeds, a.size, a.grid, inputs, say, a.scale, a.segmenter, shade)
    if a.blender:
        summary["blender"] = blender_import(a.blender_side, say)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())

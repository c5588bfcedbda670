"""``divas generate NAME --out DIR [--size N] [--seed S] [--kind 2dgs|3dgs]``: a synthetic
scene with ground truth (``--kind 3dgs``: the same scene as a trained-looking 3DGS)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import DivasInputError
from ..output_paths import check_output_path


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..synthetic import SCENE_NAMES

    p = sub.add_parser(
        "generate",
        help="write a synthetic scene with ground-truth labels (ribs, plant, occluded)",
        description="Sample a synthetic 2DGS scene on analytic surfaces and write scene.ply, "
        "cameras.json, test_cameras.json, labels.npy, surface_ids.npy and scene.json "
        "(ribs also grid.npz and grid_labels.npy, its NeRF density-grid version). "
        "--kind 3dgs writes the same scene as a standard 3DGS PLY that looks like a trained "
        "model (surface Gaussians with thickness, interior Gaussians in solid parts, large "
        "translucent Gaussians, needles, floaters) plus classes.npy.",
    )
    p.add_argument("name", choices=SCENE_NAMES, help="which scene")
    p.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    p.add_argument(
        "--kind",
        choices=("2dgs", "3dgs"),
        default="2dgs",
        help="2dgs surfels (default) or a trained-looking 3dgs PLY with exact ground truth",
    )
    p.add_argument(
        "--size", type=int, default=50_000, help="total surfel/Gaussian count (default 50000)"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--sh-degree",
        type=int,
        default=None,
        choices=(0, 1, 2, 3),
        help="SH degree of the colours (default 1 for 2dgs, 3 for 3dgs)",
    )
    p.add_argument(
        "--grid-res",
        type=int,
        default=128,
        help="cells on the longest side of the ribs NeRF grid (default 128; 2dgs only)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..synthetic import MIN_SIZE, generate_scene

    if args.size < MIN_SIZE:
        raise DivasInputError(None, f"--size {args.size} is too small (minimum {MIN_SIZE})")
    if args.grid_res < 8:
        raise DivasInputError(None, f"--grid-res {args.grid_res} is too small (minimum 8)")
    if args.out.exists() and not args.out.is_dir():
        raise DivasInputError(args.out, "--out exists and is not a folder")
    check_output_path(args.out, what="--out", folder=True)
    sc = generate_scene(
        args.name,
        args.out,
        size=args.size,
        seed=args.seed,
        sh_degree=args.sh_degree,
        grid_resolution=args.grid_res,
        kind=args.kind,
    )
    m = sc.metadata
    c = m["counts"]
    occ = m["occupancy_notes"]
    print(f"{args.name} (seed {args.seed}) → {args.out}")
    if sc.classes is None:
        print(
            f"  surfels {c['total']}: target {c['target']}, background {c['background']} "
            f"(floaters {c['floaters']}, needles {c['needles']}) on {len(sc.surfaces)} surfaces"
        )
    else:
        print(
            f"  3DGS Gaussians {c['total']}: target {c['target']} ({c['target_interior']} "
            f"inside its solids), background {c['background']}; surface {c['surface']}, "
            f"interior {c['interior']}, haze {c['haze']}, floaters {c['floaters']}, "
            f"needles {c['needles']}"
        )
    print(
        f"  cameras: {c['train_cameras']} training, {c['test_cameras']} test; "
        f"centre {[round(v, 3) for v in m['center']]}, radius {m['radius']:.3f}"
    )
    print(f"  occupancy (NOTES): r_fg {occ['r_fg']:.3f}, h_v {occ['h_v']:.4f}, g {occ['g']}")
    if sc.grid is not None:
        g = m["grid"]
        print(
            f"  NeRF grid {tuple(g['shape_dhw'])} (D,H,W), voxel {g['voxel_size']:.4f}, "
            f"{g['label_voxels']} target voxels"
        )
    if "ribs" in m:
        r = m["ribs"]
        print(f"  ribs: radius {r['rib_radius']:.4f} = {r['rib_radius_voxels']:.2f} h_v")
    if "dome_radius" in m.get("plant", {}):
        print(f"  dome radius {m['plant']['dome_radius']:.1f}")
    t = sc.timings
    print(f"  {sum(t.values()):.2f} s (" + ", ".join(f"{k} {v:.2f}" for k, v in t.items()) + ")")
    return 0

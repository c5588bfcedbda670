"""``divas eval [--scenes ribs,plant,occluded] [--size N] [--segmenters oracle,classic]
[--protocol user|clicks|noc] [--json] [--out FILE]``: the evaluation table on the
synthetic suite (``--protocol noc``: clicks to 85/90 % IoU, :mod:`..evaluation.noc`).

Per scene: scripted DivAS sessions — by default a simulated user that looks at each of
the session's anchors with the overlay of the running selection and clicks the largest
uncovered region of its target until coverage is complete (paper Sec. 3.3/3.7; it gives
up on an anchor after 2 clicks in a row without progress; at most 10 views on a
forward-facing capture, 20 on a 360° one, the paper's view budget); ``--protocol
clicks``: the metadata clicks on the training cameras that see them, every centroid view
accepted. Each with the SAM-like
oracle and the classic segmenter: DivAS full, without the thin path, without depth
weighting, Pass 1 only, Pass 1+2; and two peer baselines fed the same accepted view masks
(centre-projection voting, FlashSplat-style contribution voting); the NeRF path on the
ribs density grid. Scores at the held-out test cameras (NOTES "Evaluation": mean IoU
and pixel accuracy; alpha fidelity, opacity-weighted IoU and the PSNR of the selection
rendered alone) and per primitive (precision / recall). See
:mod:`divas_engine.evaluation.suite`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..errors import DivasInputError
from ..output_paths import check_output_path, write_text_atomic

#: Default surfels per scene: the whole table (3 scenes × 2 segmenters + NeRF) runs in
#: a few minutes on 2 CPU cores.
DEFAULT_SIZE = 20_000


def _csv(choices: tuple[str, ...], what: str):
    def parse(s: str) -> tuple[str, ...]:
        items = tuple(x.strip() for x in s.split(",") if x.strip())
        bad = [x for x in items if x not in choices]
        if not items or bad:
            raise argparse.ArgumentTypeError(
                f"{what} must be a comma-separated subset of {','.join(choices)} (got {s!r})"
            )
        return tuple(dict.fromkeys(items))

    return parse


def _int_list(s: str) -> tuple[int, ...]:
    try:
        items = tuple(int(x) for x in s.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {s!r}") from None
    if not items or len(set(items)) != len(items):
        raise argparse.ArgumentTypeError(f"expected distinct comma-separated integers, got {s!r}")
    return items


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..synthetic import SCENE_NAMES
    from ..synthetic.scenes import SUITE_SCENES

    p = sub.add_parser(
        "eval",
        help="evaluation table on the synthetic suite (IoU, accuracy, "
        "precision/recall; ablations and baselines)",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    p.add_argument(
        "--scenes",
        type=_csv(tuple(SCENE_NAMES), "--scenes"),
        default=None,
        help=f"comma-separated synthetic scenes of {','.join(SCENE_NAMES)} (default "
        f"{','.join(SUITE_SCENES)}; with --protocol noc every scene)",
    )
    p.add_argument(
        "--size", type=int, default=DEFAULT_SIZE, help=f"surfels per scene (default {DEFAULT_SIZE})"
    )
    p.add_argument("--seed", type=int, default=0, help="scene / segmenter seed (default 0)")
    p.add_argument(
        "--seeds",
        type=_int_list,
        default=None,
        help="comma-separated seeds: run the suite once per seed and check the "
        "targets on the per-scene means (overrides --seed)",
    )
    p.add_argument(
        "--segmenters",
        type=_csv(("oracle", "graph3d", "classic"), "--segmenters"),
        default=None,
        help="comma-separated subset of oracle,graph3d,classic (default oracle,classic; "
        "with --protocol noc graph3d,oracle,classic)",
    )
    p.add_argument("--no-nerf", action="store_true", help="skip the NeRF path on the ribs grid")
    p.add_argument(
        "--grid-resolution",
        type=int,
        default=128,
        help="ribs NeRF grid cells along its longest side (default 128)",
    )
    p.add_argument(
        "--baseline-masks",
        choices=("raw", "weighted"),
        default="raw",
        help="masks fed to the baselines: the segmenter's (raw, default) or "
        "DivAS's depth-weighted ones",
    )
    p.add_argument(
        "--protocol",
        choices=("user", "clicks", "noc"),
        default="user",
        help="view protocol: the simulated user clicking uncovered target regions "
        "under the overlay on the session's anchors (user, default, the "
        "paper's Sec. 3.3/3.7), the metadata clicks on training cameras "
        "(clicks, the divas demo protocol), or noc: the interactive-segmentation "
        "metric (RITM-style user, IoU after 1..--max-clicks clicks, NoC@85/90, "
        "tuning and held-out halves apart; evaluation.noc)",
    )
    p.add_argument(
        "--max-clicks",
        type=int,
        default=10,
        help="--protocol noc: clicks per scene and target (default 10)",
    )
    p.add_argument(
        "--real-targets",
        type=Path,
        default=None,
        help="--protocol noc: also every real-capture target of this data folder "
        "(the repository's tests/data)",
    )
    p.add_argument(
        "--clicks-per-anchor",
        type=int,
        default=None,
        help="simulated user: hard cap on clicks per anchor (default: none — it "
        "works an anchor until complete, or until 2 clicks in a row make no "
        "progress)",
    )
    p.add_argument(
        "--max-views",
        type=int,
        default=None,
        help="simulated user: centroid views per session (default: the paper's "
        "bounded view processing, 10 forward-facing / 20 for 360° captures)",
    )
    p.add_argument(
        "--manual-anchors",
        type=int,
        default=None,
        help="simulated user: training cameras it may add as manual anchors after "
        "the plan's anchors (paper: manual anchor selection; default 4; 0 = the "
        "automatic anchors only)",
    )
    p.add_argument(
        "--eval-scale",
        type=float,
        default=1.0,
        help="render the test cameras at this fraction of their size (default 1)",
    )
    p.add_argument(
        "--no-fidelity",
        action="store_true",
        help="skip alpha fidelity, opacity-weighted IoU and extracted-object PSNR "
        "(one render of each selection alone per test camera)",
    )
    p.add_argument(
        "--kind",
        choices=("2dgs", "3dgs"),
        default="2dgs",
        help="the scenes as 2DGS surfels (default) or as their trained-looking 3DGS "
        "variants (divas generate --kind 3dgs; adds the w/o-completion row, no NeRF path)",
    )
    p.add_argument(
        "--no-ablations",
        action="store_true",
        help="skip the w/o-thin-path and w/o-depth-weighting sessions",
    )
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument(
        "--json", action="store_true", help="print one JSON object instead of the Markdown table"
    )
    p.add_argument("--out", type=Path, default=None, help="also write the JSON result here")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from divas_kernels import resolve_device

    from ..evaluation.metrics import EvalConfig
    from ..evaluation.suite import SuiteConfig, evaluate_suite, markdown_table
    from ..synthetic import MIN_SIZE
    from ..synthetic.scenes import SUITE_SCENES

    if args.size < MIN_SIZE:
        raise DivasInputError(None, f"--size {args.size} is too small (minimum {MIN_SIZE})")
    if not args.eval_scale > 0:
        raise DivasInputError(None, f"--eval-scale must be positive, got {args.eval_scale}")
    if args.grid_resolution < 8:
        raise DivasInputError(None, "--grid-resolution must be ≥ 8")
    if args.out is not None:
        check_output_path(args.out, what="--out")
    try:
        dev = resolve_device(args.device)
    except RuntimeError as e:
        raise DivasInputError(None, str(e)) from None
    if args.protocol == "noc":
        return _run_noc(args, dev)
    args.scenes = args.scenes or SUITE_SCENES
    args.segmenters = args.segmenters or ("oracle", "classic")
    from ..evaluation.scripted_user import UserBudget

    ub = UserBudget()
    try:
        ub = UserBudget(
            clicks_per_anchor=ub.clicks_per_anchor
            if args.clicks_per_anchor is None
            else int(args.clicks_per_anchor),
            max_views=ub.max_views if args.max_views is None else int(args.max_views),
            manual_anchors=ub.manual_anchors
            if args.manual_anchors is None
            else int(args.manual_anchors),
        )
    except ValueError as e:
        raise DivasInputError(None, str(e)) from None
    cfg = SuiteConfig(
        protocol=args.protocol,
        user=ub,
        scenes=tuple(args.scenes),
        segmenters=tuple(args.segmenters),
        size=int(args.size),
        seed=int(args.seed),
        seeds=tuple(args.seeds or ()),
        nerf=not args.no_nerf,
        grid_resolution=int(args.grid_resolution),
        baseline_masks=args.baseline_masks,
        eval=EvalConfig(scale=float(args.eval_scale)),
        fidelity=not args.no_fidelity,
        kind=args.kind,
        ablations=not args.no_ablations,
    )
    t0 = time.perf_counter()
    log = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    result = evaluate_suite(cfg, device=dev, log=log)
    result["device"] = str(dev)
    result["wall_s"] = time.perf_counter() - t0
    if _emit(args, result):
        print(markdown_table(result))
        print(
            f"\n{len(result['rows'])} rows, protocol {cfg.protocol}, size {cfg.size}, "
            f"seed{'s' if len(cfg.run_seeds) > 1 else ''} "
            f"{','.join(map(str, cfg.run_seeds))}, device {dev}, "
            f"{result['wall_s']:.0f} s"
        )
    return 0


def _run_noc(args: argparse.Namespace, dev) -> int:
    """``--protocol noc``: the NoC table of the synthetic scenes (``--kind``) and, with
    ``--real-targets``, every real target."""
    from ..evaluation.noc import NocConfig
    from ..evaluation.noc_suite import noc_table, real_cases, run_cases, summary, synthetic_cases
    from ..synthetic import SCENE_NAMES

    if args.max_clicks < 1:
        raise DivasInputError(None, f"--max-clicks must be ≥ 1, got {args.max_clicks}")
    if args.real_targets is not None and not (args.real_targets / "targets").is_dir():
        raise DivasInputError(args.real_targets, "no targets/ folder here (use tests/data)")
    cfg = NocConfig(max_clicks=int(args.max_clicks), eval_scale=float(args.eval_scale))
    cases = synthetic_cases(args.scenes or SCENE_NAMES, [args.kind])
    if args.real_targets is not None:
        cases += real_cases()
    segs = args.segmenters or ("graph3d", "oracle", "classic")
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    rows = run_cases(
        cases,
        segs,
        size=int(args.size),
        seed=int(args.seed),
        config=cfg,
        data_dir=args.real_targets,
        device=dev,
        log=say,
    )
    result = {"rows": rows, "summary": summary(rows, cfg.thresholds), "device": str(dev)}
    result["wall_s"] = time.perf_counter() - t0
    if _emit(args, result):
        print(noc_table(rows, cfg.thresholds))
        print(
            f"\n{len(rows)} runs, protocol noc, size {args.size}, device {dev}, "
            f"{result['wall_s']:.0f} s"
        )
    return 0


def _emit(args: argparse.Namespace, result: dict) -> bool:
    """Write the JSON result to ``--out``, print it with ``--json``; whether the caller
    prints its table instead."""
    text = json.dumps(result, default=_json_default)
    if args.out is not None:
        write_text_atomic(args.out, text)
    if args.json:
        print(text)
    return not args.json


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


__all__ = ["add_parser", "run", "DEFAULT_SIZE"]

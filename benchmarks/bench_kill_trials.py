"""``kill -9`` trials of ``divas segment --session``: lost sessions, resumes.

    python benchmarks/bench_kill_trials.py [--random 30] [--torn 2,3,4,5,6,7,8,9] [--seed 14]
    PYTHONPATH=/path/to/other/checkout python benchmarks/bench_kill_trials.py --no-resume

Runs the harness of ``tests/kill_harness.py`` on a generated 4,000-surfel ribs scene
(4 clicks, classic segmenter, render scale 0.125): one uninterrupted reference run, then
``--random`` children SIGKILLed at seeded delays ~ U(0, 1.1 × the reference), and one
child per ``--torn`` k killed at its k-th rename onto the session manifest (the window
between the arrays file and the manifest). Prints, per set: trials, kills, sessions on
disk, lost (on disk but unreadable), resumes equal to the reference, and runs that left
temporaries. ``--no-resume`` measures a checkout without ``--resume`` (loadability only);
with ``PYTHONPATH`` pointing at another checkout the same harness measures that code.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _harness():
    """``tests/kill_harness.py`` of this checkout, by path: ``divas_engine`` itself comes
    from ``PYTHONPATH`` when set (to measure another checkout), else the installed one."""
    spec = importlib.util.spec_from_file_location("kill_harness", REPO / "tests/kill_harness.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["kill_harness"] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--random", type=int, default=30)
    ap.add_argument("--torn", default="2,3,4,5,6,7,8,9")
    ap.add_argument("--seed", type=int, default=14)
    ap.add_argument("--no-resume", action="store_true")
    args = ap.parse_args()

    import divas_engine
    import divas_engine.cli.segment  # noqa: F401 - warm before forking
    import divas_engine.session  # noqa: F401

    kh = _harness()

    print(f"code: {Path(divas_engine.__file__).parent}")
    root = Path(tempfile.mkdtemp(prefix="divas_kill_"))
    case = kh.make_case(root / "scene")
    resume = not args.no_resume
    t0 = time.perf_counter()
    t_ref, rand, labels = kh.run_trials(
        case, root / "random", args.random, args.seed, resume=resume
    )
    ks = [int(k) for k in args.torn.split(",") if k]
    torn = kh.run_torn_trials(case, root / "torn", ks, labels, resume=resume)
    out = {
        "reference_run_s": round(t_ref, 2),
        "random": kh.summary(rand),
        "torn": kh.summary(torn),
        "lost_detail": [r.problem for r in rand + torn if r.session_on_disk and not r.loads],
        "wall_s": round(time.perf_counter() - t0, 1),
        "folder": str(root),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

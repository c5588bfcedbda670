"""Fuzz every input loader and print the outcome table.

Mutated copies of small valid seed files (``tests/fuzz_cases.py``) go through each
loader in a forked child with a memory limit and a timeout. The table counts, per
loader family: ``ok`` (loaded and sane), ``input`` (refused with DivasInputError),
``garbage`` (loaded with NaN/Inf or out-of-range values), ``crash`` (any other
exception), ``hang`` (timeout) and ``memory`` (MemoryError under the limit).

    python benchmarks/fuzz_loaders.py [--cases 30000] [--seed 0] [--families ply,spz]
        [--timeout 20] [--mem-mib 1536] [--work /tmp/divas_fuzz] [--json out.json]

``--cases`` is the total, split evenly over the families (the session family, whose
cases replay a session, gets a tenth of a share).
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.fuzz_cases import FAMILIES, OUTCOMES, build_seeds, run_family  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=30_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--mem-mib", type=int, default=1536)
    ap.add_argument("--work", default=None)
    ap.add_argument("--json", default=None, help="also write the table and failures here")
    ap.add_argument("--show", type=int, default=3, help="failures listed per family/outcome")
    a = ap.parse_args(argv)
    fams = [f for f in a.families.split(",") if f]
    work = Path(a.work or tempfile.mkdtemp(prefix="divas_fuzz_"))
    t0 = time.time()
    families = build_seeds(work / "seeds", fams)
    weights = {f: (0.1 if f == "session" else 1.0) for f in fams}
    share = a.cases / sum(weights.values())
    print(
        f"# divas loader fuzz: {a.cases} cases, seed {a.seed}, timeout {a.timeout:g} s, "
        f"memory limit +{a.mem_mib} MiB; {platform.node()} {platform.machine()} "
        f"{platform.python_version()}, {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC"
    )
    header = f"{'loader':16}" + "".join(f"{o:>9}" for o in OUTCOMES) + f"{'total':>9}{'s':>8}"
    print(header, flush=True)
    table, fails = {}, {}
    for f in fams:
        n = max(1, round(share * weights[f]))
        t = time.time()
        res = run_family(
            families[f], n, a.seed, work / "cases" / f, timeout=a.timeout, mem_bytes=a.mem_mib << 20
        )
        counts = {o: len(res[o]) for o in OUTCOMES}
        table[f] = counts
        fails[f] = {o: res[o][: a.show] for o in ("garbage", "crash", "hang", "memory") if res[o]}
        print(
            f"{f:16}"
            + "".join(f"{counts[o]:>9}" for o in OUTCOMES)
            + f"{n:>9}{time.time() - t:>8.0f}",
            flush=True,
        )
    tot = {o: sum(table[f][o] for f in fams) for o in OUTCOMES}
    print(
        f"{'TOTAL':16}"
        + "".join(f"{tot[o]:>9}" for o in OUTCOMES)
        + f"{sum(tot.values()):>9}{time.time() - t0:>8.0f}"
    )
    for f, by in fails.items():
        for o, items in by.items():
            for k, detail in items:
                print(f"  {f} case {k}: {o}: {detail}")
    if a.json:
        Path(a.json).write_text(json.dumps({"table": table, "failures": fails}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Scene-loader benchmark: wall time and peak RSS of ``load_scene`` on large PLYs.

Writes random standard 3DGS PLYs (SH degree 3, 62 float properties per row, the
heaviest common layout) of the requested sizes into a scratch folder, then
loads each in a fresh subprocess so the peak RSS is the loader's own.

    python benchmarks/bench_load.py [--sizes 1000000,6000000] [--dir /tmp/divas_bench]
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from divas_engine import load_scene
s = load_scene(sys.argv[1])
dt = time.perf_counter() - t0
print(json.dumps({"seconds": dt, "count": len(s), "sh_degree": s.sh_degree,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def write_random_3dgs(path: Path, n: int, seed: int = 0, chunk: int = 1 << 20) -> None:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(45)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    dtype = np.dtype([(f, "<f4") for f in names])
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {f}\n" for f in names) + "end_header\n"
    rng = np.random.default_rng(seed)
    with open(path, "wb") as f:
        f.write(header.encode())
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            flat = rng.standard_normal((m, len(names)), dtype=np.float32)
            flat[:, names.index("scale_0") : names.index("scale_2") + 1] -= 4
            flat.view(dtype).tofile(f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000000,6000000")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/divas_bench"))
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    print(
        f"# load_scene benchmark — {platform.processor() or platform.machine()}, "
        f"{datetime.date.today()}, Python {platform.python_version()}"
    )
    print("| surfels | file MB | best wall s | peak RSS MB | rows/s |")
    print("|---:|---:|---:|---:|---:|")
    for n in (int(s) for s in args.sizes.split(",")):
        path = args.dir / f"random_3dgs_sh3_{n}.ply"
        if not path.exists():
            t = time.perf_counter()
            write_random_3dgs(path, n)
            print(f"(wrote {path} in {time.perf_counter() - t:.1f} s)", file=sys.stderr)
        runs = []
        for _ in range(args.repeats):
            out = subprocess.run(
                [sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True
            )
            runs.append(json.loads(out.stdout))
        best = min(runs, key=lambda r: r["seconds"])
        print(
            f"| {n:,} | {path.stat().st_size / 2**20:,.0f} | {best['seconds']:.2f} | "
            f"{max(r['peak_rss_mb'] for r in runs):,.0f} | {n / best['seconds']:,.0f} |"
        )


if __name__ == "__main__":
    main()

"""Scene-loader benchmark: wall time and peak RSS of ``load_scene`` on large scenes.

* PLY: random standard 3DGS PLYs (SH degree 3, 62 float properties per row, the
  heaviest common layout) of the requested sizes (``--sizes``);
* SOG (``--sog-sizes``): version 2 with 3 SH bands and a 65,536-entry palette (what
  splat-transform writes for 1M Gaussians), random texel bytes (valid quaternion
  tags and labels; incompressible, so WebP decoding is at its slowest), written
  both bundled (``.sog``) and unbundled (``meta.json`` folder).

Each file is written once into a scratch folder, then loaded in a fresh subprocess
so the peak RSS is the loader's own.

    python benchmarks/bench_load.py [--sizes 1000000,6000000] [--sog-sizes 1000000]
        [--dir /tmp/divas_bench]
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


def write_random_sog(path: Path, n: int, seed: int = 0) -> None:
    """A random SOG v2 of ``n`` Gaussians (bundled if ``path`` ends in ``.sog``)."""
    import zipfile

    from divas_engine.io.sog_subset import encode_webp_lossless, sog_texture_size

    rng = np.random.default_rng(seed)
    w, h = sog_texture_size(n)
    palette, coeffs = 65_536, 15

    def texels(shape=(h, w)):
        a = rng.integers(0, 256, (*shape, 4), dtype=np.uint8)
        a[..., 3] = 255
        return a

    imgs = {k: texels() for k in ("means_l", "means_u", "scales", "sh0", "shN_labels")}
    imgs["quats"] = texels()
    imgs["quats"][..., 3] = rng.integers(252, 256, (h, w))
    imgs["sh0"][..., 3] = rng.integers(1, 256, (h, w))
    imgs["shN_labels"][..., 2] = 0
    imgs["shN_centroids"] = texels((palette // 64, 64 * coeffs))
    cb = [sorted(rng.uniform(lo, hi, 256).tolist()) for lo, hi in ((-9, -1), (-3, 3), (-1, 1))]
    meta = {
        "version": 2,
        "count": n,
        "means": {"mins": [-3.0] * 3, "maxs": [3.0] * 3, "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": cb[0], "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": cb[1], "files": ["sh0.webp"]},
        "shN": {"count": palette, "bands": 3, "codebook": cb[2],
                "files": ["shN_centroids.webp", "shN_labels.webp"]},
    }  # fmt: skip
    files = {"meta.json": json.dumps(meta).encode()}
    files |= {f"{k}.webp": encode_webp_lossless(v, k) for k, v in imgs.items()}
    if path.suffix == ".sog":
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
            for name, data in files.items():
                zf.writestr(name, data)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (path.parent / name).write_bytes(data)


def _size_mb(path: Path) -> float:
    files = path.parent.iterdir() if path.name == "meta.json" else [path]
    return sum(f.stat().st_size for f in files) / 2**20


def _bench(label: str, path: Path, n: int, repeats: int) -> None:
    runs = []
    for _ in range(repeats):
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True
        )
        runs.append(json.loads(out.stdout))
    best = min(runs, key=lambda r: r["seconds"])
    print(
        f"| {label} | {n:,} | {_size_mb(path):,.1f} | {best['seconds']:.2f} | "
        f"{max(r['peak_rss_mb'] for r in runs):,.0f} | {n / best['seconds']:,.0f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000000,6000000")
    ap.add_argument("--sog-sizes", default="1000000", help="'' to skip SOG")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/divas_bench"))
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    print(
        f"# load_scene benchmark — {platform.processor() or platform.machine()}, "
        f"{datetime.date.today()}, Python {platform.python_version()}"
    )
    print("| format | surfels | file MB | best wall s | peak RSS MB | rows/s |")
    print("|---|---:|---:|---:|---:|---:|")
    for n in (int(s) for s in args.sizes.split(",") if s):
        path = args.dir / f"random_3dgs_sh3_{n}.ply"
        if not path.exists():
            t = time.perf_counter()
            write_random_3dgs(path, n)
            print(f"(wrote {path} in {time.perf_counter() - t:.1f} s)", file=sys.stderr)
        _bench("PLY 3DGS SH3", path, n, args.repeats)
    for n in (int(s) for s in args.sog_sizes.split(",") if s):
        for label, path in (
            ("SOG v2 SH3 bundled", args.dir / f"random_sog_sh3_{n}.sog"),
            ("SOG v2 SH3 folder", args.dir / f"random_sog_sh3_{n}" / "meta.json"),
        ):
            if not path.exists():
                t = time.perf_counter()
                write_random_sog(path, n)
                print(f"(wrote {path} in {time.perf_counter() - t:.1f} s)", file=sys.stderr)
            _bench(label, path, n, args.repeats)


if __name__ == "__main__":
    main()

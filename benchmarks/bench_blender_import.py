"""Blender import of a large 3DGS scene: time, peak RSS and the saved .blend size.

    python benchmarks/bench_blender_import.py [--splats 3000000] [--degree 3] [--evaluate]

Writes a synthetic 3DGS PLY (62 float properties per row at SH degree 3, the reference
trainer's layout) once into ``build/bench`` (reused), then imports it in a fresh ``bpy``
process with the add-on's default options and prints the import time, the process's
peak RSS (``ru_maxrss``, the whole process: Blender itself included), its CPU time
(``process_time``: on a shared machine the wall time also counts waiting), the attributes
stored and the size of the saved ``.blend``; ``read_s`` / ``read_cpu_s`` are the part
of the import that is the engine's file read (``load_scene``). ``--evaluate`` also
evaluates the display (Geometry Nodes) once, as the first viewport redraw or render would.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

_CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {repo!r})
import bpy
import addon_utils
addon_utils.enable("blender_addon", default_set=True)
bpy.ops.wm.read_homefile(app_template="")
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
import blender_addon.importers as imp
_plain_load, _read = imp.load_scene, {{}}
def _timed_load(*a, **k):  # the engine's file read, apart from the rest of the import
    t, c = time.perf_counter(), time.process_time()
    out = _plain_load(*a, **k)
    _read["read_s"], _read["read_cpu_s"] = time.perf_counter() - t, time.process_time() - c
    return out
imp.load_scene = _timed_load
t0, c0 = time.perf_counter(), time.process_time()
assert bpy.ops.divas.import_splats(filepath={ply!r}, display_mode={mode!r}) == {{"FINISHED"}}
t_import, c_import = time.perf_counter() - t0, time.process_time() - c0
rss_import = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
obj = bpy.context.active_object
out = {{"import_s": t_import, "import_cpu_s": c_import, "rss_before_mb": base / 1024,
        "rss_import_mb": rss_import / 1024, "points": len(obj.data.points),
        "attributes": len(obj.data.attributes), **_read}}
if {evaluate!r}:
    t0 = time.perf_counter()
    cam = bpy.data.objects.get("Camera")
    if cam is not None:  # a camera move forces a fresh evaluation of the display
        cam.location.x += 0.01
    dg = bpy.context.evaluated_depsgraph_get()
    obj.evaluated_get(dg)
    out["evaluate_s"] = time.perf_counter() - t0
    out["faces"] = sum(len(i.object.data.polygons) for i in dg.object_instances
                       if i.object.name == obj.name and i.object.type == "MESH")
    out["rss_evaluated_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
bpy.ops.wm.save_as_mainfile(filepath={blend!r}, compress=False)
print("RESULT " + json.dumps(out))
"""


def make_ply(path: Path, n: int, degree: int, seed: int = 0) -> None:
    """A synthetic 3DGS PLY of ``n`` Gaussians (written in 1M-row blocks)."""
    k1 = (degree + 1) ** 2 - 1
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * k1)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    dt = np.dtype([(nm, "<f4") for nm in names])
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n" + "".join(f"property float {nm}\n" for nm in names)
    ) + "end_header\n"
    rng = np.random.default_rng(seed)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        for start in range(0, n, 1_000_000):
            m = min(1_000_000, n - start)
            rows = np.zeros(m, dt)
            for i, a in enumerate("xyz"):
                rows[a] = rng.normal(scale=(2.0, 1.0, 2.0)[i], size=m)
            for nm in names[6:]:
                if nm.startswith("f_"):
                    rows[nm] = rng.normal(scale=0.3 if nm.startswith("f_rest") else 1.0, size=m)
            rows["opacity"] = rng.normal(size=m)
            for i in range(3):
                rows[f"scale_{i}"] = rng.uniform(-6, -3, m)
            for i in range(4):
                rows[f"rot_{i}"] = rng.normal(size=m)
            rows.tofile(f)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splats", type=int, default=3_000_000)
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--evaluate", action="store_true")
    ap.add_argument("--show-as", choices=("AUTO", "SPLATS", "POINTS"), default="AUTO")
    args = ap.parse_args(argv)
    folder = REPO / "build" / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    ply = folder / f"gauss_{args.splats}_sh{args.degree}.ply"
    if not ply.exists():
        make_ply(ply, args.splats, args.degree)
    with tempfile.TemporaryDirectory() as tmp:
        blend = Path(tmp) / "scene.blend"
        code = _CHILD.format(
            repo=str(REPO),
            ply=str(ply),
            blend=str(blend),
            evaluate=args.evaluate,
            mode=args.show_as,
        )
        res = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=False
        )
        line = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
        if res.returncode or not line:
            print(res.stdout[-3000:], res.stderr[-3000:], file=sys.stderr)
            return 1
        out = json.loads(line[0][7:])
        out["ply_mb"] = ply.stat().st_size / 2**20
        out["blend_mb"] = blend.stat().st_size / 2**20
    out["load_average"] = [round(x, 1) for x in __import__("os").getloadavg()]
    print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

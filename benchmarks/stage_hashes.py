"""Hash of every stage and every file of the 2DGS synthetic generator, and which
stage's last bits change with the CPU code paths numpy / OpenBLAS pick.

``hashes`` runs ``generate_scene(name, dir, size, seed, grid_resolution)`` with the
generator's steps wrapped, and prints one short SHA-256 per step (all its calls, in
call order) and per written file. ``compare`` runs ``hashes`` in subprocesses under
emulated CPUs (``NPY_DISABLE_CPU_FEATURES`` switches numpy's SIMD dispatch off feature
by feature, ``OPENBLAS_CORETYPE`` picks OpenBLAS's kernels) and prints, per variant,
the first call whose output differs from the native run, and the stages and files that
differ.

    python benchmarks/stage_hashes.py hashes [--scenes ribs plant occluded]
    python benchmarks/stage_hashes.py compare [--scenes ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

_AVX512 = "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"
_AVX512 += " AVX512_SPR"
#: name → environment of an emulated CPU (numpy 1.26 dispatch names, OpenBLAS core names)
VARIANTS: dict[str, dict[str, str]] = {
    "numpy AVX2 (no AVX-512)": {"NPY_DISABLE_CPU_FEATURES": _AVX512},
    "numpy SSE4.2 (no AVX)": {"NPY_DISABLE_CPU_FEATURES": f"{_AVX512} AVX2 FMA3 F16C AVX"},
    **{
        f"OpenBLAS {core}": {"OPENBLAS_CORETYPE": core}
        for core in (
            "Prescott",
            "Nehalem",
            "Sandybridge",
            "Haswell",
            "Zen",
            "SkylakeX",
            "Cooperlake",
            "SapphireRapids",
        )
    },
    "numpy AVX2 + OpenBLAS Zen": {"NPY_DISABLE_CPU_FEATURES": _AVX512, "OPENBLAS_CORETYPE": "Zen"},
}


def digest(obj) -> str:
    """SHA-256 of a value's exact bits: arrays (dtype, shape, bytes), floats by ``repr``,
    dataclasses / containers / plain objects field by field."""
    h = hashlib.sha256()
    _feed(h, obj)
    return h.hexdigest()


def _feed(h, obj) -> None:
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"A{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, (np.generic, float, int, bool, str, bytes, type(None))):
        h.update(repr(obj).encode() if not isinstance(obj, bytes) else obj)
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            h.update(str(k).encode())
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"L{len(obj)}".encode())
        for v in obj:
            _feed(h, v)
    elif dataclasses.is_dataclass(obj):
        _feed(h, {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)})
    elif hasattr(obj, "__dict__"):
        _feed(h, {k: v for k, v in vars(obj).items() if not k.startswith("_")})
    else:
        h.update(repr(obj).encode())


class Recorder:
    """Wraps named functions so that each call's output is hashed, in call order."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str]] = []
        self._undo: list[tuple[object, str, object]] = []
        self.names: list[str] = []

    def wrap(self, owner, attr: str, stage: str) -> None:
        """Wrap ``owner.attr`` (or ``owner[attr]`` for a dict)."""
        fn = owner[attr] if isinstance(owner, dict) else getattr(owner, attr)

        def wrapped(*args, **kwargs):
            out = fn(*args, **kwargs)
            self.calls.append((stage, digest(out)))
            return out

        self._undo.append((owner, attr, fn))
        self.names.append(stage)
        _set(owner, attr, wrapped)

    def restore(self) -> None:
        for owner, attr, fn in reversed(self._undo):
            _set(owner, attr, fn)
        self._undo.clear()

    def stages(self) -> dict[str, str]:
        by = {name: hashlib.sha256() for name in self.names}
        for stage, d in self.calls:
            by[stage].update(d.encode())
        return {k: v.hexdigest() for k, v in by.items()}


def _set(owner, attr: str, value) -> None:
    if isinstance(owner, dict):
        owner[attr] = value
    else:
        setattr(owner, attr, value)


def _instrument(rec: Recorder) -> None:
    import divas_engine.synthetic as syn
    import divas_engine.synthetic.builder as b
    import divas_engine.synthetic.grid as g
    from divas_engine.synthetic.scenes import SCENE_BUILDERS
    from divas_engine.synthetic.surfaces import Surface

    for name in list(SCENE_BUILDERS):
        rec.wrap(SCENE_BUILDERS, name, "1 layout (surfaces, cameras)")
    rec.wrap(b, "allocate_counts", "2 counts per surface")
    rec.wrap(Surface, "sample", "3 surface samples (points, normals, tangents)")
    rec.wrap(b, "surfel_scales", "4 surfel scales")
    rec.wrap(b, "_rotations", "5 tangent frames")
    rec.wrap(Surface, "distance", "6 surface distances (floaters, clicks, grid)")
    rec.wrap(b, "scene_floaters", "7 floater positions")
    rec.wrap(b, "_random_rotations", "8 floater rotations")
    rec.wrap(b, "rotmat_to_quat", "9 quaternions")
    rec.wrap(b, "quat_to_rotmat", "9 quaternions")
    rec.wrap(b, "surface_colors", "10 colours (value noise)")
    rec.wrap(syn, "build_surfels", "11 assembled surfels (SH, shuffle)")
    rec.wrap(b, "visibility", "12 click visibility")
    rec.wrap(syn, "choose_clicks", "13 clicks")
    rec.wrap(syn, "notes_grid_params", "14 occupancy sizing (metadata)")
    rec.wrap(g, "surface_colors", "15 grid colours")
    rec.wrap(syn, "voxelize", "16 density grid and labels")
    import warp

    rec.wrap(warp, "launch", "17 Warp kernel launches")


def file_hashes(folder: Path) -> dict[str, str]:
    return {p.name: digest(p.read_bytes()) for p in sorted(folder.iterdir())}


def run_hashes(scenes: list[str], size: int, seed: int, grid: int) -> dict:
    from divas_engine.synthetic import generate_scene

    out = {}
    for name in scenes:
        rec = Recorder()
        _instrument(rec)
        try:
            with tempfile.TemporaryDirectory() as d:
                generate_scene(name, d, size=size, seed=seed, grid_resolution=grid)
                files = file_hashes(Path(d))
        finally:
            rec.restore()
        out[name] = {"calls": rec.calls, "stages": rec.stages(), "files": files}
    return out


def _print_hashes(res: dict) -> None:
    for name, r in res.items():
        print(f"== {name}")
        for stage in sorted(r["stages"], key=lambda s: int(s.split()[0])):
            n = sum(1 for s, _ in r["calls"] if s == stage)
            print(f"  {r['stages'][stage][:16]}  {stage}  ({n} calls)")
        for f, h in r["files"].items():
            print(f"  {h[:16]}  file {f}")


def _child(args, env: dict[str, str]) -> dict:
    cmd = [sys.executable, __file__, "hashes", "--json", "--size", str(args.size)]
    cmd += ["--seed", str(args.seed), "--grid", str(args.grid), "--scenes", *args.scenes]
    full = {**os.environ, **env}
    p = subprocess.run(cmd, env=full, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise RuntimeError(f"{env}: {p.stderr.strip()[-2000:]}")
    return json.loads(p.stdout)


def compare(args) -> None:
    native = _child(args, {})
    print("native run:", native["features"])
    for label, env in VARIANTS.items():
        try:
            res = _child(args, env)
        except RuntimeError as e:
            print(f"-- {label}: could not run ({e})")
            continue
        print(f"-- {label}: {res['features']}")
        for name in args.scenes:
            a, b = native[name], res[name]
            first = next(
                (
                    (i, s)
                    for i, ((s, x), (_, y)) in enumerate(zip(a["calls"], b["calls"]))
                    if x != y
                ),
                None,
            )
            stages = [s for s in a["stages"] if a["stages"][s] != b["stages"].get(s)]
            files = [f for f in a["files"] if a["files"][f] != b["files"].get(f)]
            if first is None and not files:
                print(f"  {name}: identical ({len(a['calls'])} calls, {len(files)} files)")
                continue
            where = "none" if first is None else f"call {first[0]} in '{first[1]}'"
            print(f"  {name}: first differing output: {where}")
            print(f"    stages differing: {stages}")
            print(f"    files differing:  {files}")


def _numpy_features() -> str:
    """numpy's dispatched SIMD features and the BLAS kernels this process loaded."""
    from numpy.core._multiarray_umath import __cpu_features__ as f
    from threadpoolctl import threadpool_info

    on = [k for k, v in f.items() if v and k.startswith(("AVX", "FMA"))]
    blas = [f"{i['internal_api']} {i.get('architecture')}" for i in threadpool_info()]
    return f"numpy SIMD: {' '.join(on) or 'baseline'}; BLAS: {', '.join(blas)}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("hashes", "compare"))
    ap.add_argument("--scenes", nargs="+", default=["ribs", "plant", "occluded"])
    ap.add_argument("--size", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--grid", type=int, default=16)
    ap.add_argument("--json", action="store_true", help="hashes: print JSON (for compare)")
    args = ap.parse_args(argv)
    if args.mode == "compare":
        compare(args)
        return 0
    res = run_hashes(args.scenes, args.size, args.seed, args.grid)
    if args.json:
        print(json.dumps({**res, "features": _numpy_features()}))
    else:
        print(_numpy_features())
        _print_hashes(res)
        print("warp imported:", "warp" in sys.modules)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""An export (and ``divas segment --out``) onto its own input: is the input kept?

    python benchmarks/bench_out_equals_input.py
    PYTHONPATH=/path/to/other/checkout python benchmarks/bench_out_equals_input.py

For each exportable format (standard PLY from a generated ribs scene, a hand-made
``.splat``, ``biker.spz``, ``guitar.compressed.ply``, the ``playcanvas-logo`` SOG folder)
a copy is loaded and ``export_selection(scene, every 3rd row, the input's own path)``
runs in a forked child (a SIGBUS would kill only the child); then ``divas segment
scene.ply --out scene.ply`` on the ribs scene. Prints per case: the child's exit, the
error it reported, and whether every input byte is unchanged.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"


def _digest(path: Path) -> str:
    files = sorted(p for p in path.parent.rglob("*") if p.is_file()) if path.is_dir() else [path]
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


def _child(fn) -> tuple[int, str]:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        msg, code = "ok", 0
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - reported to the parent
            msg, code = f"{type(e).__name__}: {e}"[:160], 1
        os.write(w, msg.encode())
        os._exit(code)
    os.close(w)
    _, status = os.waitpid(pid, 0)
    msg = os.read(r, 4096).decode()
    return os.waitstatus_to_exitcode(status), msg or "(no message: killed)"


def main() -> None:
    import divas_engine
    from divas_engine import cli, load_scene
    from divas_engine.evaluation.demo_prompts import demo_prompts
    from divas_engine.export import export_selection
    from divas_engine.io.splat import SPLAT_DTYPE
    from divas_engine.synthetic import generate_scene

    print(f"code: {Path(divas_engine.__file__).parent}")
    root = Path(tempfile.mkdtemp(prefix="divas_outin_"))
    sc = generate_scene("ribs", root / "ribs", size=4000, seed=0, grid_resolution=16)
    demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(root / "ribs/prompts.json")
    rec = np.zeros(64, SPLAT_DTYPE)
    rec["pos"] = np.random.default_rng(0).normal(size=(64, 3))
    rec["scale"], rec["rgba"], rec["rot"] = 0.05, 200, [255, 128, 128, 128]
    rec.tofile(root / "s.splat")
    shutil.copy(DATA / "playcanvas-splats/biker.spz", root / "biker.spz")
    shutil.copy(DATA / "playcanvas-splats/guitar.compressed.ply", root / "g.ply")
    shutil.copytree(DATA / "playcanvas-sog/playcanvas-logo", root / "logo")
    cases = {
        "ply": root / "ribs/scene.ply",
        "splat": root / "s.splat",
        "spz": root / "biker.spz",
        "compressed_ply": root / "g.ply",
        "sog": root / "logo/meta.json",
    }
    rows = []
    for fmt, src in cases.items():
        work = src.with_name("copy_" + src.name) if fmt != "sog" else src
        if fmt != "sog":
            shutil.copy(src, work)
        before = _digest(work.parent if fmt == "sog" else work)
        scene = load_scene(work)
        sel = np.zeros(len(scene), bool)
        sel[::3] = True
        code, msg = _child(lambda s=scene, w=work: export_selection(s, sel, w))
        same = _digest(work.parent if fmt == "sog" else work) == before
        rows.append({"case": f"export {fmt} onto itself", "exit": code, "error": msg, "kept": same})
    ply = root / "ribs/scene.ply"
    before = _digest(ply)
    argv = ["segment", str(ply), "--prompts", str(root / "ribs/prompts.json"), "--out", str(ply)]
    argv += ["--segmenter", "classic", "--scale", "0.125", "--no-progress", "--device", "cpu"]

    def seg():
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        rc = cli.main(argv)
        if rc:
            raise SystemExit(rc)

    code, msg = _child(seg)
    rows.append(
        {
            "case": "divas segment --out = input",
            "exit": code,
            "error": msg,
            "kept": _digest(ply) == before,
        }
    )
    for r in rows:
        print(json.dumps(r))
    print(f"inputs kept: {sum(r['kept'] for r in rows)} of {len(rows)}", file=sys.stderr)


if __name__ == "__main__":
    main()

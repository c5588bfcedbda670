"""``divas batch`` against ``divas segment`` run one scene after another.

Generated scenes (``--scenes``, default 3: ribs, plant, occluded, then again with
another seed; ``--size`` surfels each, their demo prompts), segmented

* **serial**: one ``divas segment`` process per scene, one after the other (a shell loop);
* **processes**: one ``divas batch`` with ``--executor processes --workers N``;
* **ray** (when Ray is installed): ``divas batch --executor ray --workers N`` — a local
  Ray started and stopped inside the timing.

Every run is a fresh process, timed from launch to exit; the modes alternate, so a
change in the machine's load hits them alike. Printed side by side: each repeat's wall
seconds, the median, its ratio to serial, the CPU seconds (the serial runs' processes;
a batch's jobs' own, the ``cpu_s`` of each job's record: the fork server's one-time
imports and Ray's own processes are not counted) and the load average before each
run. Every batch job's labels are checked bit-identical to the serial run's.

    python benchmarks/bench_batch.py [--size 50000] [--scenes 3] [--repeats 3] [--workers 2]
        [--cpus-per-job C] [--no-ray]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

KINDS = ("ribs", "plant", "occluded")


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _timed(cmd: list[str]) -> tuple[float, float, float]:
    """``(wall s, children CPU s, 1-min load before)`` of one command (must succeed)."""
    load = os.getloadavg()[0]
    c0, t0 = _children_cpu(), time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr[-3000:]}")
    cpu = _children_cpu() - c0
    if "batch" in cmd:  # its jobs' own CPU seconds (fork-server and Ray workers are
        # not this process's children): the sum of their records' cpu_s
        jobs = [json.loads(ln) for ln in r.stdout.splitlines() if ln.startswith("{")]
        cpu = sum(float(j.get("cpu_s") or 0.0) for j in jobs)
    return wall, cpu, load


def _scenes(root: Path, size: int, names: list[str]) -> Path:
    from divas_engine.evaluation import demo_prompts
    from divas_engine.synthetic import generate_scene

    jobs = []
    for k, name in enumerate(names):
        sc = generate_scene(KINDS[k % 3], root / name, size=size, seed=k // 3)
        demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(root / name / "p.json")
        jobs.append({"scene": f"{name}/scene.ply", "prompts": f"{name}/p.json", "output": name})
    m = root / "manifest.json"
    m.write_text(json.dumps({"version": 1, "defaults": {"device": "cpu"}, "jobs": jobs}))
    return m


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=50_000, help="surfels per scene")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenes", type=int, default=3, help="jobs (ribs, plant, occluded, …)")
    ap.add_argument(
        "--cpus-per-job", type=float, default=None, help="passed to divas batch (default its own)"
    )
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray mode")
    ap.add_argument("--dir", type=Path, default=None, help="scratch folder (default: a temp)")
    args = ap.parse_args()
    from divas_engine.cli.batch_executors import ray_available

    modes = ["serial", "processes"] + (["ray"] if ray_available() and not args.no_ray else [])
    root = Path(tempfile.mkdtemp(prefix="bench_batch_", dir=args.dir))
    names = [f"{KINDS[k % 3]}{k // 3}" for k in range(args.scenes)]
    share = [] if args.cpus_per_job is None else ["--cpus-per-job", str(args.cpus_per_job)]
    divas = [sys.executable, "-m", "divas_engine"]
    try:
        manifest = _scenes(root, args.size, names)
        runs: dict[str, list[tuple[float, float, float]]] = {m: [] for m in modes}
        for k in range(args.repeats):
            order = modes if k % 2 == 0 else modes[::-1]
            for mode in order:
                out = root / f"{mode}_{k}"
                out.mkdir()
                if mode == "serial":
                    load = os.getloadavg()[0]
                    wall = cpu = 0.0
                    for name in names:
                        w, c, _ = _timed(
                            divas
                            + ["segment", str(root / name / "scene.ply")]
                            + ["--prompts", str(root / name / "p.json"), "--device", "cpu"]
                            + ["--out", str(out / f"{name}.ply")]
                            + ["--labels-out", str(out / f"{name}.npy"), "--no-progress"]
                        )
                        wall, cpu = wall + w, cpu + c
                    runs[mode].append((wall, cpu, load))
                else:
                    m = out / "manifest.json"
                    doc = json.loads(manifest.read_text())
                    for j in doc["jobs"]:
                        j["scene"], j["prompts"] = (str(root / j[x]) for x in ("scene", "prompts"))
                    m.write_text(json.dumps(doc))
                    runs[mode].append(
                        _timed(
                            divas
                            + ["batch", str(m), "--executor", mode]
                            + ["--workers", str(args.workers), "--no-progress", *share]
                        )
                    )
        for k in range(args.repeats):  # every batch job's labels are the serial run's
            for mode in modes:
                for name in names:
                    ref = np.load(root / "serial_0" / f"{name}.npy")
                    f = root / f"{mode}_{k}" / (f"{name}.npy" if mode == "serial" else name)
                    got = np.load(f if mode == "serial" else f / "labels.npy")
                    assert np.array_equal(got, ref), f"{mode} run {k}, {name}: labels differ"
    finally:
        shutil.rmtree(root, ignore_errors=True)
    serial = statistics.median(w for w, _, _ in runs["serial"])
    print(
        f"# divas batch vs divas segment one after another — {datetime.date.today()}, "
        f"{_cpu()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
    )
    print(
        f"# {len(names)} scenes ({', '.join(names)}), {args.size:,} surfels each, graph3d, "
        f"device cpu; --workers {args.workers} {' '.join(share)}; {args.repeats} repeats, "
        "modes alternating; labels bit-identical to the serial run's: yes"
    )
    print("| mode | wall s per repeat | median s | ratio to serial | CPU s | load before |")
    print("|---|---|---:|---:|---:|---|")
    for mode in modes:
        walls = [w for w, _, _ in runs[mode]]
        med = statistics.median(walls)
        cpu = statistics.median(c for _, c, _ in runs[mode])
        print(
            f"| {mode} | {', '.join(f'{w:.1f}' for w in walls)} | {med:.1f} | "
            f"{med / serial:.2f} | {cpu:.1f} | "
            f"{', '.join(f'{x:.1f}' for _, _, x in runs[mode])} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

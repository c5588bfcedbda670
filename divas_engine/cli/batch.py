"""``divas batch MANIFEST``: many ``divas segment`` runs as independent jobs.

Each manifest row (:mod:`.batch_manifest`) is one job (:mod:`.batch_jobs`) writing the
selection, ``labels.npy`` and ``report.json`` into its output folder — the labels those
of ``divas segment`` with the same inputs. Jobs run on Ray (a local one, or the cluster
at ``--address``; ``pip install 'divas[cluster]'``) or, without Ray, in a pool of local
processes: the same job function either way (:mod:`.batch_executors`). Jobs start
largest scene first (:func:`~.batch_jobs.largest_first`), so a batch does not end on one
large scene while the other workers idle.

Output: one JSON line per finished job on stdout (``job``, ``status`` —
``done``/``skipped``/``failed`` —, ``scene``, ``output``, ``seconds`` in the worker,
``cpu_s`` of the worker process, ``wall_s`` from dispatch to record, ``timings``,
``counts``, ``memory`` (the worker's peak RSS: one process per job), ``report``: the
job's report, ``error`` for a failed job); a progress bar over the jobs and a summary
table on stderr. A rerun skips the jobs whose report and outputs are complete; a job
that fails is reported and the others go on. Exit status 1 when a job failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from ..errors import DivasInputError
from .batch_jobs import job_done, job_record, largest_first


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "batch",
        help="segment many scenes from a manifest (JSON or CSV), on Ray or local processes",
        description="Run each manifest row as its own `divas segment` job (selection, "
        "labels.npy and report.json in the row's output folder), on Ray (pip install "
        "'divas[cluster]': a local Ray, or a cluster with --address) or in local "
        "processes. A rerun skips finished jobs. One JSON line per job on stdout.",
    )
    p.add_argument(
        "manifest", type=Path, help="jobs: .json, or CSV (docs: divas_engine/cli/batch_manifest.py)"
    )
    p.add_argument(
        "--executor",
        choices=("auto", "ray", "processes"),
        default="auto",
        help="where jobs run (default auto: Ray when installed, else local processes)",
    )
    p.add_argument(
        "--address",
        default=None,
        help="an existing Ray cluster (e.g. auto, or ray://head:10001); default: a local Ray",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="jobs at once (default: one per CPU here; on a cluster: as Ray schedules them)",
    )
    p.add_argument(
        "--cpus-per-job",
        type=float,
        default=None,
        help="each job's CPU share: Ray's num_cpus and the job's kernel threads (default: "
        "1 on Ray; with local processes, the cores shared out among the workers)",
    )
    p.add_argument(
        "--gpus-per-job",
        type=float,
        default=0.0,
        help="GPU share per job, in (0, 1] (Ray: num_gpus; processes: jobs per local "
        "device = floor(1 / share)); default 0: none requested",
    )
    p.add_argument(
        "--memory-per-job",
        type=float,
        default=None,
        metavar="GB",
        help="Ray: memory reserved per job (scheduling; a job over it may be killed by "
        "Ray's memory monitor)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _mb(rec: dict[str, Any]) -> str:
    m = (rec.get("memory") or {}).get("peak_rss_bytes")
    return f"{m / 2**20:,.0f}" if m else "—"


def summary_table(records: list[dict[str, Any]], wall: float, executor: str) -> str:
    """The batch's closing table: one line per job, then the totals."""
    rows = [
        "| job | status | s (worker) | CPU s | selected | peak MB | note |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for r in sorted(records, key=lambda r: r["index"]):
        counts = r.get("counts") or {}
        note = (r.get("error") or "").replace("|", "/")
        if len(note) > 80:
            note = note[:79] + "…"
        secs, cpu = r.get("seconds"), r.get("cpu_s")
        rows.append(
            f"| {r['job']} | {r['status']} | {'—' if secs is None else f'{secs:.1f}'} | "
            f"{'—' if cpu is None else f'{cpu:.1f}'} | {counts.get('selected', '—')} | "
            f"{_mb(r)} | {note} |"
        )
    n = {s: sum(r["status"] == s for r in records) for s in ("done", "skipped", "failed")}
    busy = sum(r.get("seconds") or 0.0 for r in records if r["status"] == "done")
    rows.append(
        f"{len(records)} jobs on {executor}: {n['done']} done, {n['skipped']} skipped, "
        f"{n['failed']} failed; {wall:.1f} s wall, {busy:.1f} s of jobs"
    )
    return "\n".join(rows)


def _print_line(rec: dict[str, Any]) -> None:
    from .segment import _json_default  # the report's JSON conversions

    sys.stdout.write(json.dumps(rec, default=_json_default) + "\n")
    sys.stdout.flush()


def run(args: argparse.Namespace) -> int:
    from .batch_executors import make_executor, start_pool

    start_pool(args.executor, args.address)  # its imports run beside the driver's

    from tqdm import tqdm

    from .batch_manifest import read_manifest

    if args.workers is not None and args.workers < 1:
        raise DivasInputError(None, f"--workers must be ≥ 1, got {args.workers}")
    if not 0 <= args.gpus_per_job <= 1:
        raise DivasInputError(None, f"--gpus-per-job must be in [0, 1], got {args.gpus_per_job}")
    if args.memory_per_job is not None and not args.memory_per_job > 0:
        raise DivasInputError(None, f"--memory-per-job must be positive, got {args.memory_per_job}")
    if args.cpus_per_job is not None and not args.cpus_per_job > 0:
        raise DivasInputError(None, f"--cpus-per-job must be positive, got {args.cpus_per_job}")
    jobs = read_manifest(args.manifest)
    t0 = time.perf_counter()
    records: list[dict[str, Any]] = []
    todo = []
    for job in jobs:  # finished jobs the driver can see are skipped without a worker
        done = job_done(job)
        if done is None:
            todo.append(job)
        else:
            c = done.get("counts")
            records.append(job_record(job, "skipped", counts=c, memory=done.get("memory")))
            _print_line(records[-1])
    bar = tqdm(
        total=len(jobs),
        initial=len(records),
        desc="jobs",
        unit="job",
        file=sys.stderr,
        disable=args.no_progress,
        dynamic_ncols=True,
    )
    executor_name = "nothing to run"
    if todo:
        ex = make_executor(
            args.executor,
            workers=args.workers,
            address=args.address,
            cpus_per_job=args.cpus_per_job,
            gpus_per_job=args.gpus_per_job,
            memory_per_job=args.memory_per_job,
        )
        executor_name = f"{ex.name}" + (f" ({ex.slots} at once)" if ex.slots else "")
        try:
            for rec in ex.run(largest_first(todo)):
                _print_line(rec)  # the report goes out with its line; the table needs less
                records.append({k: v for k, v in rec.items() if k not in ("report", "traceback")})
                bar.update(1)
                if rec["status"] == "failed":
                    bar.write(f"job {rec['job']} failed: {rec.get('error')}", file=sys.stderr)
        finally:
            ex.close()
    bar.close()
    print(summary_table(records, time.perf_counter() - t0, executor_name), file=sys.stderr)
    failed = sum(r["status"] == "failed" for r in records)
    return 1 if failed else 0


__all__ = ["add_parser", "run", "summary_table"]

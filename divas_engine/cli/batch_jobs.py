"""One ``divas batch`` job: what a worker runs, and whether it is already done.

A job is a :class:`~divas_engine.segment_request.SegmentRequest` (a manifest row) and
its output folder. :func:`run_job` — the function every executor runs, in a worker
process — writes into that folder, as ``divas segment`` would with the same inputs:

* the selection, named by the scene's format (:func:`selection_name`),
* ``labels.npy`` (bool per input row),
* ``report.json`` last: the ``divas segment`` report plus ``batch`` (the job's name and
  its request as given, :meth:`BatchJob.spec`).

Each file is written atomically, the report after the others, so a job is complete
exactly when its report holds the same request and every output it lists exists
(:func:`job_done`): a killed batch, run again, skips the jobs that finished. A job
never raises: a failure is a record with ``status: "failed"`` and its message.
"""

from __future__ import annotations

import json
import os
import resource
import socket
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..errors import DivasInputError
from ..segment_request import SegmentRequest

__all__ = [
    "BatchJob",
    "REPORT",
    "LABELS",
    "selection_name",
    "job_done",
    "run_job",
    "job_record",
    "largest_first",
]

REPORT = "report.json"
LABELS = "labels.npy"

#: selection file (or folder) per scene format, as ``divas segment --out`` would take it.
_SELECTION = {
    "ply": "selection.ply",
    "compressed_ply": "selection.compressed.ply",
    "splat": "selection.splat",
    "spz": "selection.spz",
    "lod": "selection",
    "npz": "selection.npz",
}


@dataclass(frozen=True)
class BatchJob:
    """Manifest row ``index``: its ``name``, ``request`` (no outputs set) and ``output``
    folder."""

    index: int
    name: str
    request: SegmentRequest
    output: Path

    def spec(self) -> dict[str, Any]:
        """The request as given (JSON): what a finished job's report must hold."""
        return self.request.to_dict()


def selection_name(scene: Path) -> str:
    """The selection's name in a job folder for the scene at ``scene`` (its format:
    a bundled SOG gives ``selection.sog``, a SOG or LOD folder a ``selection`` folder)."""
    from ..io.load import detect_format

    fmt = detect_format(scene)
    if fmt == "sog":
        return "selection.sog" if scene.suffix.lower() == ".sog" else "selection"
    return _SELECTION[fmt]


def _read_report(job: BatchJob) -> dict[str, Any] | None:
    try:
        doc = json.loads((job.output / REPORT).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def job_done(job: BatchJob) -> dict[str, Any] | None:
    """The report of a finished job (same request, every listed output present), else None."""
    rep = _read_report(job)
    if rep is None or not isinstance(rep.get("batch"), dict):
        return None
    if rep["batch"].get("request") != job.spec():
        return None
    outs = rep.get("outputs")
    if not isinstance(outs, dict) or "out" not in outs:
        return None
    listed = [outs["out"]] + ([outs["labels_out"]] if "labels_out" in outs else [])
    if not all(isinstance(p, str) and Path(p).exists() for p in listed):
        return None
    return rep


def scene_bytes(scene: Path) -> int:
    """Bytes of a scene as the driver sees it: a file's size; a folder's files summed (a
    SOG folder, an LOD tree: given as its folder or its ``meta.json`` / ``lod-meta.json``);
    0 when the driver cannot read it (a path only the workers reach)."""
    try:
        root = scene.parent if scene.name.lower().endswith("meta.json") else scene
        if root.is_dir():
            return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())
        return scene.stat().st_size
    except OSError:
        return 0


def largest_first(jobs: list[BatchJob]) -> list[BatchJob]:
    """The jobs, largest scene first (manifest order among equals; unreadable sizes last):
    longest-processing-time-first, so a batch does not end on one large scene alone
    while the other workers idle."""
    size = {j.index: scene_bytes(Path(j.request.scene)) for j in jobs}
    return sorted(jobs, key=lambda j: -size[j.index])


def job_record(job: BatchJob, status: str, **fields: Any) -> dict[str, Any]:
    """One finished job as the batch's JSON line reports it."""
    return {
        "job": job.name,
        "index": job.index,
        "status": status,
        "scene": str(job.request.scene),
        "output": str(job.output),
        **fields,
    }


def _summary(rep: dict[str, Any]) -> dict[str, Any]:
    t = rep.get("timings", {})
    return {
        "timings": {k: t[k] for k in ("T_pipe_s", "load_s", "open_s", "export_s") if k in t},
        "counts": rep.get("counts"),
        "memory": rep.get("memory"),
    }


def run_job(job: BatchJob, threads: int | None = None) -> dict[str, Any]:
    """Run ``job`` here (a worker process of its own): its outputs, then its record
    (never raises). ``threads``: the job's CPU share, the kernels' launch threads."""
    from divas_kernels import THREADS_ENV

    from .segment import segment_scene, write_report

    if threads is not None:
        os.environ[THREADS_ENV] = str(max(1, int(threads)))
    t0 = time.perf_counter()
    where = {"host": socket.gethostname(), "pid": os.getpid()}
    try:
        done = job_done(job)
        if done is not None:
            return job_record(job, "skipped", **where, **_summary(done), report=done)
        job.output.mkdir(parents=True, exist_ok=True)
        req = replace(
            job.request,
            out=job.output / selection_name(job.request.scene),
            labels_out=job.output / LABELS,
        )
        report, _ = segment_scene(req, progress=False)
        report["batch"] = {"job": job.name, "request": job.spec()}
        write_report(job.output / REPORT, report)
        ru = resource.getrusage(resource.RUSAGE_SELF)
        return job_record(
            job,
            "done",
            seconds=time.perf_counter() - t0,
            cpu_s=ru.ru_utime + ru.ru_stime,  # the worker process's: imports included
            **where,
            **_summary(report),
            report=report,
        )
    except DivasInputError as e:
        return job_record(job, "failed", seconds=time.perf_counter() - t0, **where, error=str(e))
    except Exception as e:  # noqa: BLE001 - a job's bug is its record, not the batch's end
        return job_record(
            job,
            "failed",
            seconds=time.perf_counter() - t0,
            **where,
            error=f"{type(e).__name__}: {e}",
            traceback=traceback.format_exc(),
        )

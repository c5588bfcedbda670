"""Where ``divas batch`` jobs run: Ray, or a plain pool of local processes.

Both executors are one small interface (:class:`JobExecutor`): ``run(jobs)`` yields
each job's record as it finishes, in finishing order. Both run
:func:`~.batch_jobs.run_job` in a fresh process per job, so a job's peak memory is its
own, a crash takes only its job down, and nothing leaks from one job into the next.

* :class:`RayExecutor` — each job a Ray task (``num_cpus``, ``num_gpus`` per job,
  ``max_calls=1``), on a local Ray started here or on the cluster at ``address``. Jobs
  carry paths, never scene bytes: each worker reads its inputs where it runs.
* :class:`ProcessExecutor` — at most ``workers`` local processes at a time (forked
  warm from a server that has imported the engine on Linux, spawned elsewhere); with
  ``gpus_per_job`` each process sees one of this machine's CUDA devices
  (``CUDA_VISIBLE_DEVICES``), ``floor(1 / gpus_per_job)`` jobs per device.

Each job's CPU share is its kernels' launch threads: jobs side by side do not each split
every launch over all the cores. Local processes share the cores out among the jobs
running, again whenever one starts or ends (a job reads its share at every launch), so
the last job of a batch runs on every core; ``--cpus-per-job`` fixes the share instead.

A worker that dies (killed, out of memory) gives a failed record for its job; the
other jobs go on.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from multiprocessing.connection import wait
from typing import Any

from ..errors import DivasInputError
from .batch_jobs import BatchJob, job_record, run_job

__all__ = [
    "JobExecutor",
    "ProcessExecutor",
    "RayExecutor",
    "make_executor",
    "ray_available",
    "start_pool",
]


class JobExecutor(ABC):
    """Runs batch jobs; ``name`` and ``slots`` (jobs at once; None: the cluster decides)
    describe it in the batch's summary."""

    name: str
    slots: int | None

    @abstractmethod
    def run(self, jobs: Sequence[BatchJob]) -> Iterator[dict[str, Any]]:
        """Yield every job's record (:func:`~.batch_jobs.run_job`) as it finishes."""

    @abstractmethod
    def close(self) -> None:
        """Release what the executor started (processes, a local Ray)."""


def _child(job: BatchJob, conn, gpu: int | None, share) -> None:
    """A pool process: one job, its record sent back; ``share``: a shared integer, the
    job's launch threads, read at every launch. Its stdout goes to stderr (the batch's
    stdout carries one JSON line per job)."""
    from divas_kernels import set_thread_source

    os.dup2(2, 1)
    if gpu is not None:
        os.environ["CUDA_VISIBLE_DEVICES"] = str(gpu)
    set_thread_source(lambda: share.value)
    conn.send(run_job(job, None))
    conn.close()


def _death(code: int | None) -> str:
    if code is not None and code < 0:
        import signal

        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = " (out of memory?)" if -code == signal.SIGKILL else ""
        return f"the worker process was killed by {name}{hint}"
    return f"the worker process exited with status {code} before reporting"


def _cuda_devices() -> int:
    from divas_kernels import cuda_device_count

    return int(cuda_device_count())


def _job_context():
    """Linux: a fork server that has imported the job's modules
    (:mod:`.batch_preload`), so each job forks warm and still runs alone; elsewhere
    spawned processes."""
    if sys.platform.startswith("linux"):
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["divas_engine.cli.batch_preload"])
        return ctx
    return mp.get_context("spawn")


class ProcessExecutor(JobExecutor):
    """Jobs in local processes, ``workers`` at a time (module docstring)."""

    name = "processes"

    def __init__(self, workers: int, gpus_per_job: float = 0.0, cpus_per_job: int | None = None):
        from divas_kernels import usable_cores

        self.cores = usable_cores()
        self.fixed = cpus_per_job
        self.threads = cpus_per_job or max(1, self.cores // max(1, int(workers)))
        self.gpus: list[int | None] = [None] * max(1, int(workers))
        if gpus_per_job > 0:
            n = _cuda_devices()
            if n == 0:
                raise DivasInputError(None, "--gpus-per-job: this machine has no CUDA device")
            per = max(1, math.floor(1.0 / gpus_per_job))
            self.gpus = [d for d in range(n) for _ in range(per)][: max(1, int(workers))]
        self.slots = len(self.gpus)
        self._ctx = _job_context()
        self._running: dict[Any, tuple] = {}

    def run(self, jobs: Sequence[BatchJob]) -> Iterator[dict[str, Any]]:
        todo = list(jobs)
        free = list(self.gpus)
        try:
            while todo or self._running:
                while todo and free:
                    job, gpu = todo.pop(0), free.pop(0)
                    recv, send = self._ctx.Pipe(duplex=False)
                    share = self._ctx.RawValue("i", self.threads)
                    p = self._ctx.Process(target=_child, args=(job, send, gpu, share), daemon=True)
                    p.start()
                    send.close()
                    self._running[recv] = (p, job, gpu, time.perf_counter(), share)
                    self._deal()
                for conn in wait(list(self._running)):
                    p, job, gpu, t0, _ = self._running.pop(conn)
                    self._deal()
                    try:
                        rec = conn.recv()
                    except (EOFError, OSError):
                        rec = None
                    conn.close()
                    p.join()
                    free.append(gpu)
                    if rec is None:
                        rec = job_record(job, "failed", error=_death(p.exitcode))
                    rec["wall_s"] = time.perf_counter() - t0
                    yield rec
        finally:
            self.close()

    def _deal(self) -> None:
        """Share the cores out among the running jobs (each at least one thread; the
        first ones get the remainder); a fixed ``cpus_per_job`` stays."""
        if self.fixed or not self._running:
            return
        n = len(self._running)
        base, extra = divmod(self.cores, n)
        for k, (*_, share) in enumerate(self._running.values()):
            share.value = max(1, base + (k < extra))

    def close(self) -> None:
        for conn, (p, *_) in list(self._running.items()):
            if p.is_alive():
                p.kill()
            p.join()
            conn.close()
        self._running.clear()


def ray_available() -> bool:
    """Whether Ray is installed (found, not imported: importing it takes a second)."""
    from importlib.util import find_spec

    try:
        return find_spec("ray") is not None
    except (ImportError, ValueError):
        return False


def start_pool(kind: str, address: str | None) -> None:
    """Start the process pool's fork server now when the batch will use one (``kind`` and
    ``address`` as :func:`make_executor` takes them), so its imports run beside the
    driver's reading of the manifest and its own imports instead of before the first
    job."""
    if kind == "auto":
        kind = "ray" if (address is not None or ray_available()) else "processes"
    if kind != "processes" or not sys.platform.startswith("linux"):
        return
    from multiprocessing import forkserver

    _job_context()
    forkserver.ensure_running()


class RayExecutor(JobExecutor):
    """Jobs as Ray tasks (module docstring). ``address``: an existing cluster (None: a
    local Ray with ``workers`` × ``cpus_per_job`` CPUs, shut down by :meth:`close`)."""

    name = "ray"

    def __init__(
        self,
        address: str | None,
        workers: int | None,
        cpus_per_job: float = 1.0,
        gpus_per_job: float = 0.0,
        memory_per_job: float | None = None,
    ):
        import ray

        self._ray = ray
        self._started = False
        if not ray.is_initialized():
            kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if address is not None:
                ray.init(address=address, **kw)
            else:
                n = workers or os.cpu_count() or 1
                ray.init(num_cpus=max(1, math.ceil(n * cpus_per_job)), **kw)
                self._started = True
        self.slots = workers
        self.threads = max(1, math.floor(cpus_per_job))
        opts: dict[str, Any] = {"num_cpus": cpus_per_job, "num_gpus": gpus_per_job}
        if memory_per_job:
            opts["memory"] = int(memory_per_job * 2**30)
        self._task = ray.remote(max_calls=1, **opts)(run_job)

    def run(self, jobs: Sequence[BatchJob]) -> Iterator[dict[str, Any]]:
        ray = self._ray
        todo = list(jobs)
        running: dict[Any, tuple[BatchJob, float]] = {}
        cap = self.slots or len(todo)
        while todo or running:
            while todo and len(running) < cap:
                job = todo.pop(0)
                running[self._task.remote(job, self.threads)] = (job, time.perf_counter())
            ready, _ = ray.wait(list(running), num_returns=1)
            for ref in ready:
                job, t0 = running.pop(ref)
                try:
                    rec = ray.get(ref)
                except ray.exceptions.RayError as e:  # the worker died, or Ray failed it
                    first = str(e).strip().splitlines()
                    rec = job_record(
                        job, "failed", error=f"{type(e).__name__}: {first[0] if first else e}"
                    )
                rec["wall_s"] = time.perf_counter() - t0
                yield rec

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False


def make_executor(
    kind: str,
    *,
    workers: int | None,
    address: str | None = None,
    cpus_per_job: float | None = None,
    gpus_per_job: float = 0.0,
    memory_per_job: float | None = None,
) -> JobExecutor:
    """``kind``: ``"ray"``, ``"processes"`` or ``"auto"`` (Ray when it is installed, or
    when ``address`` is given). ``cpus_per_job``: each job's CPU share — Ray's
    ``num_cpus`` and the job's kernel launch threads (default: 1 on Ray; here, the
    cores shared out among the workers). ``memory_per_job`` (GiB): Ray's ``memory``."""
    if kind == "auto":
        kind = "ray" if (address is not None or ray_available()) else "processes"
    if kind == "ray":
        if not ray_available():
            raise DivasInputError(
                None, "Ray is not installed: pip install 'divas[cluster]' (or --executor processes)"
            )
        return RayExecutor(address, workers, cpus_per_job or 1.0, gpus_per_job, memory_per_job)
    if address is not None or memory_per_job is not None:
        what = "--address" if address is not None else "--memory-per-job"
        raise DivasInputError(None, f"{what} needs the Ray executor")
    threads = None if cpus_per_job is None else max(1, math.floor(cpus_per_job))
    return ProcessExecutor(workers or os.cpu_count() or 1, gpus_per_job, threads)

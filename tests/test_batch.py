"""``divas batch``: manifests, jobs in local processes or on Ray, resuming a killed batch.

Every job's labels are compared bit for bit with ``divas segment``'s on the same inputs,
run on this machine in this test (the point is that a batch job *is* that run). The
Ray tests start a local Ray (a few seconds): there are two, and the process pool runs
the same job function.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import divas_engine.cli as cli
from divas_engine.cli.batch_executors import ProcessExecutor, make_executor
from divas_engine.cli.batch_jobs import job_done
from divas_engine.cli.batch_manifest import read_manifest
from divas_engine.cli.segment import segment_scene
from divas_engine.errors import DivasInputError
from divas_engine.evaluation import demo_prompts
from divas_engine.segment_request import SegmentRequest
from divas_engine.synthetic import generate_scene

REPO = Path(__file__).resolve().parents[1]
LOD = REPO / "tests" / "data" / "splat-transform-lod" / "lod-meta.json"
OPTIONS = {"scale": 0.5, "device": "cpu"}


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Three small generated scenes with their prompts, and a LOD prompt (camera-free)."""
    root = tmp_path_factory.mktemp("batch")
    for name in ("ribs", "plant", "occluded"):
        sc = generate_scene(name, root / name, size=15_000, seed=1, grid_resolution=32)
        demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(root / name / "p.json")
    doc = {"version": 1, "anchors": [{"fibonacci": 0, "clicks": [{"xy": [320, 240]}]}]}
    (root / "lod_p.json").write_text(json.dumps(doc))
    return root


def _rows(root: Path, out: str) -> list[dict]:
    rows = [
        {"scene": f"{n}/scene.ply", "prompts": f"{n}/p.json", "output": f"{out}/{n}"}
        for n in ("ribs", "plant", "occluded")
    ]
    return rows


def _manifest(root: Path, name: str, rows: list[dict], defaults=OPTIONS) -> Path:
    p = root / name
    p.write_text(json.dumps({"version": 1, "defaults": defaults, "jobs": rows}))
    return p


def _reference(root: Path, rel_scene: str, rel_prompts: str, tag: str, **kw) -> np.ndarray:
    """``divas segment`` on the same inputs (in this process, on this machine)."""
    labels = root / f"ref_{tag}.npy"
    if not labels.exists():
        req = SegmentRequest(
            root / rel_scene,
            root / rel_prompts,
            out=root / f"ref_{tag}_sel",
            labels_out=labels,
            **{**OPTIONS, **kw},
        )
        segment_scene(req, progress=False)
    return np.load(labels)


def _batch(argv: list[str], capsys) -> tuple[int, list[dict], str]:
    rc = cli.main(["batch", *argv, "--no-progress"])
    cap = capsys.readouterr()
    lines = [json.loads(x) for x in cap.out.splitlines() if x.strip()]
    return rc, lines, cap.err


def test_manifest_rows_defaults_and_csv(tmp_path):
    (tmp_path / "m.csv").write_text(
        "name,scene,prompts,output,seed,up,options\n"
        'a,s/a.ply,p.json,out/a,3,"[0, 0, 1]",\n'
        'b,file:///data/b.ply,p.json,out/b,,,"{""segmenter"": ""classic""}"\n'
    )
    a, b = read_manifest(tmp_path / "m.csv")
    assert a.request.scene == tmp_path / "s" / "a.ply" and a.request.seed == 3
    assert a.request.up == (0.0, 0.0, 1.0) and a.output == tmp_path / "out" / "a"
    assert b.request.scene == Path("/data/b.ply") and b.request.segmenter == "classic"
    m = _manifest(tmp_path, "m.json", [{"scene": "x.ply", "prompts": "p", "output": "o"}])
    (j,) = read_manifest(m)
    assert j.name == "o" and j.request.scale == 0.5 and j.request.out is None


@pytest.mark.parametrize(
    "rows, says",
    [
        ([{"scene": "s", "prompts": "p"}], "jobs[0].output: missing"),
        ([{"scene": "s", "prompts": "p", "output": "o", "seed": 1}], "unknown keys ['seed']"),
        ([{"scene": "s", "prompts": "p", "output": "o", "options": {"out": "x"}}], "not an option"),
        ([{"scene": "s", "prompts": "p", "output": "o", "options": {"sede": 1}}], "unknown option"),
        (
            [{"scene": "s", "prompts": "p", "output": "o", "options": {"scale": "big"}}],
            "jobs[0].scale: must be a number",
        ),
        ([{"scene": "s", "prompts": "p", "output": "o"}] * 2, "the same name"),
        ([{"scene": "s3://b/s.ply", "prompts": "p", "output": "o"}], "only paths and file://"),
        ([], "holds no jobs"),
    ],
)
def test_bad_manifests_are_one_error_naming_the_row(tmp_path, rows, says):
    m = _manifest(tmp_path, "m.json", rows)
    with pytest.raises(DivasInputError) as e:
        read_manifest(m)
    assert says in str(e.value) and "m.json" in str(e.value)


def test_processes_give_divas_segments_labels_and_report_a_failing_job(captures, capsys):
    root = captures
    rows = _rows(root, "out_proc")
    rows.append({"scene": "missing.ply", "prompts": "ribs/p.json", "output": "out_proc/bad"})
    lod = {"scene": str(LOD), "prompts": "lod_p.json", "output": "out_proc/lod"}
    rows.append({**lod, "options": {"lod": 1, "scale": 0.25}})
    m = _manifest(root, "proc.json", rows)
    rc, lines, err = _batch([str(m), "--executor", "processes", "--workers", "2"], capsys)
    assert rc == 1  # one job failed; the others ran
    by = {r["job"]: r for r in lines}
    assert by["bad"]["status"] == "failed" and "missing.ply" in by["bad"]["error"]
    for n in ("ribs", "plant", "occluded"):
        r = by[n]
        assert r["status"] == "done" and r["report"]["counts"]["selected"] > 0
        assert r["memory"]["peak_rss_bytes"] > 0 and r["timings"]["T_pipe_s"] > 0
        got = np.load(root / "out_proc" / n / "labels.npy")
        np.testing.assert_array_equal(got, _reference(root, f"{n}/scene.ply", f"{n}/p.json", n))
        assert (root / "out_proc" / n / "selection.ply").is_file()
    assert by["lod"]["status"] == "done"
    assert (root / "out_proc" / "lod" / "selection" / "lod-meta.json").is_file()
    ref = _reference(root, str(LOD), "lod_p.json", "lod", lod=1, scale=0.25)
    np.testing.assert_array_equal(np.load(root / "out_proc" / "lod" / "labels.npy"), ref)
    assert (
        "| job | status |" in err
        and "5 jobs on processes (2 at once): 4 done, 0 skipped, 1 failed" in err
    )
    # a rerun runs only the failed job
    rc, again, err = _batch([str(m), "--executor", "processes"], capsys)
    assert rc == 1 and {r["job"]: r["status"] for r in again} == {
        "ribs": "skipped",
        "plant": "skipped",
        "occluded": "skipped",
        "lod": "skipped",
        "bad": "failed",
    }


def test_a_changed_row_is_not_taken_for_done(captures, capsys):
    root = captures
    rows = _rows(root, "out_change")[:1]
    m = _manifest(root, "change.json", rows)
    assert _batch([str(m), "--executor", "processes"], capsys)[0] == 0
    (job,) = read_manifest(m)
    assert job_done(job) is not None
    m = _manifest(root, "change.json", rows, defaults={**OPTIONS, "seed": 5})
    (job,) = read_manifest(m)
    assert job_done(job) is None  # another request: its outputs are not these
    (job.output / "labels.npy").unlink()
    m = _manifest(root, "change.json", rows)
    assert job_done(read_manifest(m)[0]) is None  # an output gone: not done


def test_a_killed_batch_rerun_finishes_only_the_missing_jobs(captures, tmp_path):
    root = captures
    m = _manifest(root, "kill.json", _rows(root, "out_kill"))
    cmd = [sys.executable, "-m", "divas_engine", "batch", str(m), "--executor", "processes"]
    cmd += ["--workers", "1", "--no-progress"]
    p = subprocess.Popen(
        cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True
    )
    first = root / "out_kill" / "ribs" / "report.json"
    t0 = time.monotonic()
    while not first.exists():
        assert p.poll() is None and time.monotonic() - t0 < 300, "the batch ended early"
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGKILL)  # the driver and its worker, halfway through
    p.wait()
    done = [
        n for n in ("ribs", "plant", "occluded") if (root / "out_kill" / n / "report.json").exists()
    ]
    assert done and len(done) < 3
    stamps = {n: (root / "out_kill" / n / "labels.npy").stat().st_mtime_ns for n in done}
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    status = {x["job"]: x["status"] for x in map(json.loads, r.stdout.splitlines())}
    assert status == {
        n: ("skipped" if n in done else "done") for n in ("ribs", "plant", "occluded")
    }
    for n in done:  # the finished jobs were not run again
        assert (root / "out_kill" / n / "labels.npy").stat().st_mtime_ns == stamps[n]
    for n in ("ribs", "plant", "occluded"):
        ref = _reference(root, f"{n}/scene.ply", f"{n}/p.json", n)
        np.testing.assert_array_equal(np.load(root / "out_kill" / n / "labels.npy"), ref)


def test_a_worker_that_dies_fails_its_job_only(captures):
    jobs = read_manifest(_manifest(captures, "die.json", _rows(captures, "out_die")[:1]))
    ex = ProcessExecutor(1)

    def kill():
        for proc, *_ in list(ex._running.values()):
            proc.kill()

    threading.Timer(0.5, kill).start()
    (rec,) = list(ex.run(jobs))
    assert rec["status"] == "failed" and "killed by SIGKILL" in rec["error"]


def test_gpu_share_needs_a_device_without_ray(monkeypatch):
    import divas_engine.cli.batch_executors as be

    monkeypatch.setattr(be, "_cuda_devices", lambda: 0)
    with pytest.raises(DivasInputError, match="no CUDA device"):
        make_executor("processes", workers=2, gpus_per_job=0.5)
    monkeypatch.setattr(be, "_cuda_devices", lambda: 2)
    ex = make_executor("processes", workers=8, gpus_per_job=0.5)
    assert ex.gpus == [0, 0, 1, 1] and ex.slots == 4


def test_ray_gives_divas_segments_labels(captures, capsys):
    pytest.importorskip("ray")
    root = captures
    m = _manifest(root, "ray.json", _rows(root, "out_ray"))
    rc, lines, err = _batch([str(m), "--executor", "ray", "--workers", "2"], capsys)
    assert rc == 0, err[-2000:]
    assert {r["status"] for r in lines} == {"done"} and "3 jobs on ray" in err
    for n in ("ribs", "plant", "occluded"):
        got = np.load(root / "out_ray" / n / "labels.npy")
        np.testing.assert_array_equal(got, _reference(root, f"{n}/scene.ply", f"{n}/p.json", n))


def test_auto_picks_ray_only_when_installed_and_a_job_gets_its_cpu_share(monkeypatch):
    import divas_engine.cli.batch_executors as be
    from divas_kernels import THREADS_ENV, cpu_threads

    monkeypatch.setattr(be, "ray_available", lambda: False)
    ex = make_executor("auto", workers=2)
    assert isinstance(ex, ProcessExecutor)
    assert ex.threads == max(1, (os.cpu_count() or 1) // 2)
    assert make_executor("auto", workers=2, cpus_per_job=3).threads == 3
    with pytest.raises(DivasInputError, match="Ray is not installed"):
        make_executor("ray", workers=2)
    with pytest.raises(DivasInputError, match="--address needs the Ray executor"):
        make_executor("processes", workers=2, address="auto")
    monkeypatch.setenv(THREADS_ENV, "3")
    assert cpu_threads() == 3 and cpu_threads(5) == 5
    monkeypatch.setenv(THREADS_ENV, "lots")
    assert cpu_threads() == len(os.sched_getaffinity(0))


def _modules_at_start(conn) -> None:
    """A job process's first act: which engine modules it starts with, its warp state."""
    conn.send(
        {
            "session": "divas_engine.session" in sys.modules,
            "warp_initialised": _warp_initialised(),
            "pid": os.getpid(),
        }
    )
    conn.close()


def _warp_initialised() -> bool:
    warp = sys.modules.get("warp")
    context = getattr(warp, "_src", None) if warp is not None else None
    runtime = getattr(getattr(context, "context", None), "runtime", None)
    return runtime is not None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork server: Linux only")
def test_job_processes_fork_warm_from_a_server_without_warp_initialised():
    from divas_engine.cli.batch_executors import _job_context

    ctx = _job_context()
    assert ctx.get_start_method() == "forkserver"
    seen = []
    for _ in range(2):  # each job its own process, both from the same preloaded server
        recv, send = ctx.Pipe(duplex=False)
        p = ctx.Process(target=_modules_at_start, args=(send,))
        p.start()
        send.close()
        seen.append(recv.recv())
        p.join()
    assert all(s["session"] for s in seen)  # the engine imported before the job began
    assert not any(s["warp_initialised"] for s in seen)  # no device context before a fork
    assert seen[0]["pid"] != seen[1]["pid"] != os.getpid()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork server: Linux only")
def test_the_fork_server_starts_before_the_driver_reads_the_manifest(monkeypatch):
    import multiprocessing.forkserver as fs

    import divas_engine.cli.batch_executors as be

    started = []
    monkeypatch.setattr(fs, "ensure_running", lambda: started.append(True))
    monkeypatch.setattr(be, "ray_available", lambda: True)
    be.start_pool("auto", None)  # Ray runs the jobs: no pool
    be.start_pool("ray", None)
    be.start_pool("processes", None)
    assert started == [True]
    monkeypatch.setattr(be, "ray_available", lambda: False)
    be.start_pool("auto", None)
    be.start_pool("auto", "ray://head:10001")  # a cluster: Ray
    assert started == [True, True]
    read = []
    monkeypatch.setattr(fs, "ensure_running", lambda: read.append("server"))
    import divas_engine.cli.batch_manifest as bm

    real = bm.read_manifest
    monkeypatch.setattr(bm, "read_manifest", lambda p: (read.append("manifest"), real(p))[1])
    with pytest.raises(DivasInputError):
        from divas_engine.cli import batch

        batch.run(
            cli.build_parser().parse_args(["batch", "no-such.json", "--executor", "processes"])
        )
    assert read == ["server", "manifest"]


def test_jobs_start_largest_scene_first(tmp_path):
    from divas_engine.cli.batch_jobs import BatchJob, largest_first, scene_bytes

    def scene(name: str, sizes: dict[str, int]) -> Path:
        d = tmp_path / name
        for rel, n in sizes.items():
            (d / rel).parent.mkdir(parents=True, exist_ok=True)
            (d / rel).write_bytes(b"x" * n)
        return d

    small = scene("a", {"s.ply": 10}) / "s.ply"
    big = scene("b", {"s.ply": 300}) / "s.ply"
    same = scene("c", {"s.ply": 10}) / "s.ply"
    # an LOD tree given as its manifest, a SOG folder as itself: their files summed
    lod = scene("d", {"lod-meta.json": 5, "0_0/meta.json": 50, "0_0/means_l.webp": 100})
    sog = scene("e", {"meta.json": 20, "means_l.webp": 80})
    assert scene_bytes(lod / "lod-meta.json") == 155 and scene_bytes(sog) == 100
    assert scene_bytes(tmp_path / "only-on-the-workers.ply") == 0
    paths = [small, tmp_path / "only-on-the-workers.ply", big, same, lod / "lod-meta.json", sog]
    jobs = [
        BatchJob(k, f"j{k}", SegmentRequest(scene=p, prompts=None), tmp_path / f"o{k}")
        for k, p in enumerate(paths)
    ]
    # largest first; equal sizes keep the manifest's order; an unreadable size goes last
    assert [j.index for j in largest_first(jobs)] == [2, 4, 5, 0, 3, 1]


def test_ray_is_found_without_importing_it(monkeypatch):
    from divas_engine.cli.batch_executors import ray_available

    monkeypatch.setitem(sys.modules, "ray", None)  # as if it could not be imported
    assert ray_available() is False


def _threads_seen(share, go, conn) -> None:
    """A job process's launch threads before and after the batch re-deals its share."""
    from divas_kernels import cpu_threads, set_thread_source

    set_thread_source(lambda: share.value)
    conn.send(cpu_threads())
    go.wait(60)
    conn.send((cpu_threads(), cpu_threads(7)))
    conn.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork server: Linux only")
def test_a_running_job_takes_the_cores_the_batch_deals_it():
    from divas_engine.cli.batch_executors import _job_context

    ctx = _job_context()
    share, go = ctx.RawValue("i", 1), ctx.Event()
    recv, send = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_threads_seen, args=(share, go, send))
    p.start()
    send.close()
    assert recv.recv() == 1
    share.value = 2  # the other job ended: this one now has both cores
    go.set()
    assert recv.recv() == (2, 7)  # an explicit request still wins
    p.join()


def test_the_cores_are_shared_out_among_the_running_jobs():
    import multiprocessing as mp

    ex = ProcessExecutor(3)
    ex.cores = 4
    shares = [mp.RawValue("i", 0) for _ in range(3)]
    ex._running = {k: (None, None, None, 0.0, s) for k, s in enumerate(shares)}
    ex._deal()
    assert [s.value for s in shares] == [2, 1, 1]
    del ex._running[0]  # a job ended: the two left get two cores each
    ex._deal()
    assert [s.value for s in shares[1:]] == [2, 2]
    ex.cores = 1
    ex._deal()
    assert [s.value for s in shares[1:]] == [1, 1]  # never less than one thread
    fixed = ProcessExecutor(3, cpus_per_job=3)
    fixed._running = {0: (None, None, None, 0.0, shares[0])}
    shares[0].value = 3
    fixed._deal()
    assert shares[0].value == 3  # --cpus-per-job stays

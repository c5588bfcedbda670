"""``kill -9`` trials of ``divas segment --session``, shared by
``tests/test_session_kill.py`` and ``benchmarks/bench_kill_trials.py``.

Each trial forks a child that runs ``divas segment … --session S`` (``cli.main``, the
command's own code path) and sends it ``SIGKILL`` after a seeded random delay drawn
over the length of an uninterrupted run. Forking after a warm-up run in the parent
keeps a trial at the cost of the segmentation (a fresh interpreter would spend most of
a trial importing on a shared 2-core machine); the child is a separate process, so the
kill cuts it wherever it is, writes included.

After the kill: a session on disk must load (``store.load_state`` and, via ``--resume``,
``Session.load``); ``--resume`` must finish the run to the labels of the uninterrupted
run, and leave no temporaries behind.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

TEMP_MARKERS = (".divas-tmp", ".tmp")


@dataclass
class KillCase:
    """The small ``divas segment`` run the trials kill."""

    scene: Path
    prompts: Path
    segmenter: str = "classic"
    scale: float = 0.125
    extra: tuple[str, ...] = ()

    def argv(self, out_dir: Path, *, resume: bool = False) -> list[str]:
        a = [
            "segment",
            str(self.scene),
            "--prompts",
            str(self.prompts),
            "--out",
            str(out_dir / "sel.ply"),
            "--labels-out",
            str(out_dir / "labels.npy"),
            "--session",
            str(out_dir / "session.json"),
            "--segmenter",
            self.segmenter,
            "--scale",
            str(self.scale),
            "--device",
            "cpu",
            "--no-progress",
        ]
        return a + list(self.extra) + (["--resume"] if resume else [])


def make_case(folder: Path, *, size: int = 4000, views_per_click: int = 1) -> KillCase:
    """A generated ribs scene with its demo prompts (4 clicks per view copy)."""
    from divas_engine.evaluation.demo_prompts import demo_prompts
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("ribs", folder, size=size, seed=0, grid_resolution=16)
    demo_prompts(sc.metadata, sc.cameras, views_per_click=views_per_click).write(
        folder / "prompts.json"
    )
    return KillCase(folder / "scene.ply", folder / "prompts.json")


def kill_at_manifest_rename(k: int, manifest_name: str = "session.json"):
    """A child ``prepare`` hook: SIGKILL the child at its ``k``-th rename onto the session
    manifest, just before it happens — the window between the arrays file landing and
    the manifest landing (where a non-atomic save would tear)."""

    def prepare() -> None:
        real = os.replace
        seen = [0]

        def replace(src, dst, *a, **kw):
            if Path(dst).name == manifest_name:
                seen[0] += 1
                if seen[0] == k:
                    os.kill(os.getpid(), signal.SIGKILL)
            return real(src, dst, *a, **kw)

        os.replace = replace

    return prepare


def _run_quietly(argv: list[str], log: Path, prepare=None) -> int:
    from divas_engine import cli

    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    # the parent's sys.stdout/err may be pytest's capture objects: write to the log
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    try:
        if prepare is not None:
            prepare()
        return cli.main(argv)
    except BaseException as e:  # noqa: BLE001 - the child reports and exits
        print(f"child failed: {type(e).__name__}: {e}", file=sys.stderr)
        return 99


def run_child(
    argv: list[str],
    log: Path,
    kill_after: float | None,
    prepare=None,
    *,
    wait_for: Path | None = None,
    seen: list[float] | None = None,
) -> tuple[bool, int]:
    """Fork a child running ``divas`` ``argv`` (after ``prepare()``, in the child);
    SIGKILL it ``kill_after`` seconds after its start — or, with ``wait_for``, after that
    file first appears (None: let it finish, or kill itself). ``seen`` gets the seconds
    from the start to ``wait_for``'s appearance. Returns ``(killed, exit status)``."""
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # child
        rc = 99
        try:
            rc = _run_quietly(argv, log, prepare)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(int(rc))
    t0 = time.monotonic()
    if wait_for is not None:
        while not wait_for.exists():
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return False, os.waitstatus_to_exitcode(status)
            time.sleep(0.002)
        if seen is not None:
            seen.append(time.monotonic() - t0)
    if kill_after is not None:
        t_end = time.monotonic() + kill_after
        while time.monotonic() < t_end:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return False, os.waitstatus_to_exitcode(status)
            time.sleep(min(0.005, max(t_end - time.monotonic(), 0)))
        os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    code = os.waitstatus_to_exitcode(status)
    return code == -signal.SIGKILL, code


def session_loads(path: Path) -> tuple[bool, str]:
    """Whether the session at ``path`` reads back (manifest + arrays)."""
    from divas_engine.errors import DivasInputError
    from divas_engine.session.store import load_state

    try:
        load_state(path)
    except (DivasInputError, OSError, ValueError, KeyError) as e:
        return False, str(e)
    return True, ""


def temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(TEMP_MARKERS))


@dataclass
class TrialResult:
    delay: float | None
    killed: bool
    session_on_disk: bool
    loads: bool
    problem: str = ""
    resumed_equal: bool | None = None
    temps_after_kill: list[str] = field(default_factory=list)
    temps_after_resume: list[str] = field(default_factory=list)
    arrays_files_after_resume: int = 0


def reference(case: KillCase, folder: Path, seen: list[float] | None = None):
    """An uninterrupted run in a child: (seconds, labels); ``seen`` gets the seconds to
    its first session save."""
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    sp = folder / "session.json"
    killed, code = run_child(case.argv(folder), folder / "log.txt", None, wait_for=sp, seen=seen)
    dt = time.monotonic() - t0
    if code != 0:
        raise RuntimeError(f"reference run failed ({code}): {(folder / 'log.txt').read_text()}")
    return dt, np.load(folder / "labels.npy")


def trial(
    case: KillCase,
    folder: Path,
    delay: float,
    ref_labels: np.ndarray | None,
    *,
    resume: bool = True,
    prepare=None,
    after_first_save: bool = False,
) -> TrialResult:
    """One kill at ``delay`` s (or by ``prepare``'s hook), then (``resume``) ``--resume``
    in a child and a compare with the uninterrupted labels."""
    folder.mkdir(parents=True, exist_ok=True)
    wait = folder / "session.json" if after_first_save else None
    killed, code = run_child(
        case.argv(folder), folder / "killed.txt", delay, prepare, wait_for=wait
    )
    sp = folder / "session.json"
    on_disk = sp.exists()
    ok, problem = session_loads(sp) if on_disk else (True, "")
    res = TrialResult(delay, killed, on_disk, ok, problem, temps_after_kill=temporaries(folder))
    if not killed and code != 0:
        res.loads, res.problem = False, f"run failed ({code})"
    if resume and ok:
        for f in ("labels.npy", "sel.ply"):
            (folder / f).unlink(missing_ok=True)
        _, rc = run_child(case.argv(folder, resume=True), folder / "resumed.txt", None)
        if rc != 0:
            res.problem = (folder / "resumed.txt").read_text().strip()[-300:]
            res.resumed_equal = False
        else:
            res.resumed_equal = bool(np.array_equal(np.load(folder / "labels.npy"), ref_labels))
        res.temps_after_resume = temporaries(folder)
        res.arrays_files_after_resume = len(list(folder.glob("session.json*.npz")))
    return res


def run_trials(
    case: KillCase,
    root: Path,
    n: int,
    seed: int,
    *,
    resume: bool = True,
    after_first_save: int = 0,
) -> tuple[float, list[TrialResult], np.ndarray]:
    """The reference run, then ``n`` kill trials: the first ``n − after_first_save`` with
    delays ~ U(0, 1.1 · reference) from the start, the others ~ U(0, 1.1 · (reference −
    its first save)) from the moment the session file first appears (so every one of
    those dies with a session on disk). Returns (reference s, trials, reference labels)."""
    seen: list[float] = []
    t_ref, labels = reference(case, root / "reference", seen)
    t_rest = max(t_ref - (seen[0] if seen else 0.0), 0.05)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        anchored = i >= n - after_first_save
        d = float(rng.uniform(0.0, 1.1 * (t_rest if anchored else t_ref)))
        out.append(
            trial(
                case,
                root / f"trial_{i:03d}",
                d,
                labels,
                resume=resume,
                after_first_save=anchored,
            )
        )
    return t_ref, out, labels


def run_torn_trials(
    case: KillCase, root: Path, ks, ref_labels: np.ndarray, *, resume: bool = True
) -> list[TrialResult]:
    """Targeted trials: killed at the ``k``-th manifest rename, for each ``k`` in ``ks``."""
    return [
        trial(
            case,
            root / f"torn_{k:03d}",
            None,
            ref_labels,
            resume=resume,
            prepare=kill_at_manifest_rename(k),
        )
        for k in ks
    ]


def summary(results: list[TrialResult]) -> dict:
    return {
        "trials": len(results),
        "killed": sum(r.killed for r in results),
        "session_on_disk": sum(r.session_on_disk for r in results),
        "lost_unloadable": sum(r.session_on_disk and not r.loads for r in results),
        "resumed_equal": sum(bool(r.resumed_equal) for r in results),
        "resumed_different_or_failed": sum(r.resumed_equal is False for r in results),
        "temps_left_after_kill": sum(bool(r.temps_after_kill) for r in results),
        "temps_left_after_resume": sum(bool(r.temps_after_resume) for r in results),
        "stray_arrays_after_resume": sum(r.arrays_files_after_resume > 1 for r in results),
    }


if __name__ == "__main__":  # pragma: no cover - quick manual run
    import tempfile

    root = Path(tempfile.mkdtemp())
    c = make_case(root / "scene")
    t, rs, _ = run_trials(c, root, int(sys.argv[1]) if len(sys.argv) > 1 else 5, 0)
    print(json.dumps({"reference_s": t, **summary(rs)}, indent=1))

"""``kill -9`` of ``divas segment --session`` at seeded random moments, and at the torn
window between the arrays file and the manifest.

Every killed run leaves a session that loads (or none, when it died before the first
save), no temporary survives the resume, and ``--resume`` finishes it to the labels
of the uninterrupted run. The trials fork the test process (``tests/kill_harness``):
each child is a separate process killed with SIGKILL, without paying an interpreter
start-up per trial.
"""

from __future__ import annotations

import json

import pytest

from . import kill_harness as kh

N_RANDOM = 11  # + 4 torn here, + 4 random and 1 torn on the NeRF grid: 20 kills
N_NERF = 4
#: manifest renames to die at (1 = the first save: nothing on disk yet, tested too):
#: open → 1, the 4 clicks → 2-5, the 4 accepts → 6-9, the final save → 10
TORN = (1, 2, 5, 8)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    # import before forking, so each child starts warm
    import divas_engine.cli.segment  # noqa: F401
    import divas_engine.session  # noqa: F401

    return kh.make_case(tmp_path_factory.mktemp("kill_scene"))


@pytest.fixture(scope="module")
def nerf_case(case):
    """The same ribs capture as its density grid: asynchronous SAM with pending views,
    the oracle (graph3d/classic reject every view of a 16³ grid at this scale)."""
    folder = case.scene.parent
    return kh.KillCase(
        folder / "grid.npz",
        case.prompts,
        segmenter="oracle",
        scale=0.25,
        extra=("--gt-labels", str(folder / "grid_labels.npy")),
    )


def test_kill9_at_random_points_then_resume(case, tmp_path):
    # 4 from the start (load, open …), 7 timed from the first save (all of them die with
    # a session on disk: no timing luck needed for the assertions below)
    t_ref, results, _ = kh.run_trials(case, tmp_path, N_RANDOM, seed=14, after_first_save=7)
    s = kh.summary(results)
    detail = json.dumps([r.__dict__ for r in results], default=str, indent=1)
    assert s["killed"] >= 1, detail
    assert sum(r.session_on_disk for r in results[-7:]) == 7, detail
    assert s["lost_unloadable"] == 0, detail
    assert s["resumed_equal"] == N_RANDOM, detail
    assert s["temps_left_after_resume"] == 0, detail
    assert s["stray_arrays_after_resume"] == 0, detail


def test_kill9_nerf_grid_then_resume(nerf_case, tmp_path):
    _, results, labels = kh.run_trials(nerf_case, tmp_path, N_NERF, seed=5, after_first_save=N_NERF)
    results += kh.run_torn_trials(nerf_case, tmp_path, (6,), labels)
    s = kh.summary(results)
    detail = json.dumps([r.__dict__ for r in results], default=str, indent=1)
    assert s["killed"] >= 1 and s["session_on_disk"] == N_NERF + 1, detail
    assert s["lost_unloadable"] == 0 and s["resumed_equal"] == N_NERF + 1, detail
    assert s["temps_left_after_resume"] == 0 and s["stray_arrays_after_resume"] == 0, detail


def test_kill9_in_the_torn_window_keeps_the_previous_save(case, tmp_path):
    _, labels = kh.reference(case, tmp_path / "reference")
    results = kh.run_torn_trials(case, tmp_path, TORN, labels)
    detail = json.dumps([r.__dict__ for r in results], default=str, indent=1)
    assert all(r.killed for r in results), detail
    assert [r.session_on_disk for r in results] == [k > 1 for k in TORN], detail
    assert all(r.loads and r.resumed_equal for r in results), detail
    assert all(not r.temps_after_resume for r in results), detail
    assert all(r.arrays_files_after_resume == 1 for r in results), detail


def test_resume_refuses_a_session_of_other_settings(case, tmp_path):
    _, code = kh.run_child(case.argv(tmp_path), tmp_path / "log.txt", None)
    assert code == 0
    argv = case.argv(tmp_path, resume=True)
    argv[argv.index("--scale") + 1] = "0.25"
    _, code = kh.run_child(argv, tmp_path / "other.txt", None)
    log = (tmp_path / "other.txt").read_text()
    assert code == 2 and "saved with other settings (render_scale)" in log, log
    i = argv.index("--session")
    _, code = kh.run_child(argv[:i] + argv[i + 2 :], tmp_path / "none.txt", None)
    log = (tmp_path / "none.txt").read_text()
    assert code == 2 and "--resume needs --session" in log, log

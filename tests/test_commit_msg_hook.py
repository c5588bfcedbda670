"""The commit-msg hook (``make hooks``): a one-line subject of at most 72 characters."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

HOOK = Path(__file__).resolve().parents[1] / ".githooks" / "commit-msg"

pytestmark = pytest.mark.skipif(shutil.which("sh") is None, reason="needs a POSIX sh")


def _run(tmp_path: Path, message: str) -> subprocess.CompletedProcess:
    path = tmp_path / "COMMIT_EDITMSG"
    path.write_text(message, encoding="utf-8")
    return subprocess.run(["sh", str(HOOK), str(path)], capture_output=True, text=True)


@pytest.mark.parametrize(
    "message",
    [
        "io: read SOG v2 folders\n",
        "io: read SOG v2 folders\n\nThe why, in the body.\nMore lines.\n",
        "x" * 72 + "\n",
        "é" * 72 + "\n",  # characters, not bytes
        "# a comment git strips\nfusion: exact removal of a view\n",
        "Merge branch 'a-branch-with-a-long-name' into main, with a subject past the limit\n",
    ],
)
def test_accepts_one_short_line_and_a_body(tmp_path, message):
    res = _run(tmp_path, message)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize(
    ("message", "says"),
    [
        ("x" * 73 + "\n", "73 characters"),
        ("\n\nbody only\n", "empty"),
        ("a subject\nthat runs on\n", "second line"),
    ],
)
def test_refuses_long_or_run_on_subjects(tmp_path, message, says):
    res = _run(tmp_path, message)
    assert res.returncode == 1 and says in res.stderr, res.stderr

"""The CLI matrix — bad invocations of every sub-command (hostile
files, a FIFO as the scene, out-of-range options, unwritable outputs) end with a nonzero
exit and one message, never a Python traceback; an internal error prints one line with
"please report" and the path of the saved traceback. Most run in-process through
``divas_engine.cli.main``; a few as real subprocesses (the console entry, a FIFO)."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys

import numpy as np
import pytest

import divas_engine.cli as cli
from divas_engine.evaluation import demo_prompts
from divas_engine.synthetic import generate_scene


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_matrix")
    sc = generate_scene("ribs", d / "scene", size=2000, seed=0, grid_resolution=16)
    prompts = demo_prompts(sc.metadata, sc.cameras, views_per_click=1)
    prompts.write(d / "prompts.json")
    good = d / "scene" / "scene.ply"
    data = good.read_bytes()
    end = data.index(b"end_header\n")
    lines = data[:end].decode().split("\n")
    (d / "dup.ply").write_bytes(
        ("\n".join(lines[:4] + [lines[3]] + lines[4:])).encode() + data[end:]
    )
    (d / "neg.ply").write_bytes(data.replace(b"element vertex 2000", b"element vertex -5", 1))
    (d / "bad.npz").write_bytes(b"PK\x03\x04" + b"\0" * 100)
    (d / "empty.splat").write_bytes(b"")
    cams = json.loads((d / "scene" / "cameras.json").read_text())
    huge = [dict(cams[0], width=200000, height=150000)]
    (d / "huge_cameras.json").write_text(json.dumps(huge))
    (d / "inf_cameras.json").write_text(
        json.dumps([cams[0]]).replace('"fx": ', '"fx": 1e400, "x": ')
    )
    pdoc = json.loads((d / "prompts.json").read_text())
    pdoc["centroid_prompts"] = {"\u0663:0": [{"xy": [1, 1]}]}
    (d / "bad_prompts.json").write_text(json.dumps(pdoc))
    (d / "deep_prompts.json").write_text("[" * 50_000 + "]" * 50_000)
    head = "{'descr': '|b1', 'fortran_order': False, 'shape': (100000, 100000, 100000), }"
    head = head.ljust(118) + "\n"
    (d / "huge.npy").write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", 119) + head.encode())
    fifo = d / "fifo.ply"
    os.mkfifo(fifo)
    png = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + struct.pack(">II", 10**5, 10**5)
    (d / "scene" / "huge.png").write_bytes(png + b"\0" * 20)
    return d


def _matrix(d):
    s, scene = str(d), str(d / "scene" / "scene.ply")
    pr = ["--prompts", f"{s}/prompts.json", "--no-progress", "--scale", "0.25"]
    out = ["--out", f"{s}/o.ply"]
    return {
        "info-dup": ["info", f"{s}/dup.ply"],
        "info-neg": ["info", f"{s}/neg.ply"],
        "info-npz": ["info", f"{s}/bad.npz"],
        "info-empty-splat": ["info", f"{s}/empty.splat"],
        "info-fifo": ["info", f"{s}/fifo.ply"],
        "info-dir": ["info", s],
        "info-missing": ["info", f"{s}/nothing.ply"],
        "info-device": ["info", "/dev/zero"],
        "info-huge-cameras": ["info", scene, "--cameras", f"{s}/huge_cameras.json"],
        "render-dup": ["render", f"{s}/dup.ply", "--orbit", "0,10", "--out", f"{s}/r"],
        "render-huge-cam": [
            "render",
            scene,
            "--cameras",
            f"{s}/huge_cameras.json",
            "--index",
            "0",
            "--out",
            f"{s}/r",
        ],
        "render-inf-cam": [
            "render",
            scene,
            "--cameras",
            f"{s}/inf_cameras.json",
            "--index",
            "0",
            "--out",
            f"{s}/r",
        ],
        "render-scale-100": [
            "render",
            scene,
            "--orbit",
            "0,10",
            "--scale",
            "100",
            "--out",
            f"{s}/r",
        ],
        "render-scale-nan": [
            "render",
            scene,
            "--orbit",
            "0,10",
            "--scale",
            "nan",
            "--out",
            f"{s}/r",
        ],
        "anchors-npz": ["anchors", f"{s}/bad.npz", "--out", f"{s}/a"],
        "anchors-fifo": ["anchors", f"{s}/fifo.ply", "--out", f"{s}/a"],
        "anchors-scale-0": ["anchors", scene, "--scale", "0", "--out", f"{s}/a"],
        "generate-seed-2^64": ["generate", "ribs", "--out", f"{s}/g", "--seed", str(2**64)],
        "generate-seed-neg": ["generate", "ribs", "--out", f"{s}/g", "--seed", "-1"],
        "segment-fifo": ["segment", f"{s}/fifo.ply", *pr, *out],
        "segment-dup": ["segment", f"{s}/dup.ply", *pr, *out],
        "segment-huge-cameras": [
            "segment",
            scene,
            "--cameras",
            f"{s}/huge_cameras.json",
            *pr,
            *out,
        ],
        "segment-scale-100": ["segment", scene, *pr, "--scale", "100", *out],
        "segment-seed-2^64": ["segment", scene, *pr, "--seed", str(2**64), *out],
        "segment-bad-prompts": ["segment", scene, "--prompts", f"{s}/bad_prompts.json", *out],
        "segment-deep-prompts": ["segment", scene, "--prompts", f"{s}/deep_prompts.json", *out],
        "segment-fifo-prompts": ["segment", scene, "--prompts", f"{s}/fifo.ply", *out],
        "segment-out-dir": ["segment", scene, *pr, "--out", s],
        "segment-labels-missing-dir": [
            "segment",
            scene,
            *pr,
            "--labels-out",
            f"{s}/no/such/dir/l.npy",
        ],
        "eval-missing": ["eval", f"{s}/nothing.json"],
        "info-long-name": ["info", f"{s}/{'x' * 300}.ply"],
        "segment-long-prompts-name": ["segment", scene, "--prompts", f"{s}/{'p' * 300}.json", *out],
        "segment-gt-fifo": ["segment", scene, *pr, "--gt-labels", f"{s}/fifo.ply", *out],
        "segment-gt-huge-shape": ["segment", scene, *pr, "--gt-labels", f"{s}/huge.npy", *out],
        "render-camera-json-deep": [
            "render",
            scene,
            "--camera-json",
            "[" * 50_000,
            "--out",
            f"{s}/r",
        ],
        "render-camera-json-bigint": [
            "render",
            scene,
            "--camera-json",
            '{"width": ' + "9" * 5000 + "}",
            "--out",
            f"{s}/r",
        ],
    }


CASES = [
    "info-dup", "info-neg", "info-npz", "info-empty-splat", "info-fifo", "info-dir",
    "info-missing", "info-device", "info-huge-cameras", "render-dup", "render-huge-cam",
    "render-inf-cam", "render-scale-100", "render-scale-nan", "anchors-npz", "anchors-fifo",
    "anchors-scale-0", "generate-seed-2^64", "generate-seed-neg", "segment-fifo",
    "segment-dup", "segment-huge-cameras", "segment-scale-100", "segment-seed-2^64",
    "segment-bad-prompts", "segment-deep-prompts", "segment-fifo-prompts",
    "segment-out-dir", "segment-labels-missing-dir", "eval-missing", "segment-gt-fifo",
    "segment-gt-huge-shape", "render-camera-json-deep", "render-camera-json-bigint",
    "info-long-name", "segment-long-prompts-name",
]  # fmt: skip


@pytest.mark.parametrize("case", CASES)
def test_bad_invocation_is_one_message(files, case, capsys, monkeypatch, tmp_path):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))  # where a crash file would go
    argv = _matrix(files)[case]
    try:
        rc = cli.main(argv)
    except SystemExit as e:  # argparse's own usage errors
        rc = e.code
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert rc not in (0, None), text
    assert "Traceback" not in text, text
    assert "internal error" not in text, text  # every one of these is the user's input
    assert not list(tmp_path.glob("divas-crash-*")), text
    assert cap.err.strip(), "no message"


def test_internal_error_is_one_line_with_a_saved_traceback(files, capsys, monkeypatch, tmp_path):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))

    def broken(*a, **k):
        raise ZeroDivisionError("deliberate bug")

    monkeypatch.setattr("divas_engine.io.load.load_scene", broken)
    rc = cli.main(["info", str(files / "scene" / "scene.ply")])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_INTERNAL and "Traceback" not in err
    assert "please report" in err and "ZeroDivisionError: deliberate bug" in err
    saved = list(tmp_path.glob("divas-crash-*.txt"))
    assert len(saved) == 1 and str(saved[0]) in err
    assert "Traceback" in saved[0].read_text() and "deliberate bug" in saved[0].read_text()


def test_oserror_is_one_line(files, capsys, monkeypatch):
    def denied(*a, **k):
        raise PermissionError(13, "Permission denied", "/x/out.ply")

    monkeypatch.setattr("divas_engine.io.load.load_scene", denied)
    rc = cli.main(["info", str(files / "scene" / "scene.ply")])
    err = capsys.readouterr().err
    assert rc == 1 and err.strip() == "divas info: error: Permission denied: /x/out.ply"


@pytest.mark.parametrize("case", ["info-fifo", "segment-fifo", "info-dup", "segment-scale-100"])
def test_real_subprocess(files, case):
    """The installed entry point: a FIFO scene must not hang, no traceback anywhere."""
    argv = _matrix(files)[case]
    r = subprocess.run(
        [sys.executable, "-m", "divas_engine", *argv],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode != 0 and "Traceback" not in r.stdout + r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith("Warp ")]
    assert len(lines) == 1 or "usage:" in r.stderr, r.stderr  # Warp's no-GPU notice aside
    assert lines[-1].startswith("divas "), r.stderr


def test_matrix_lists_every_case(files):
    assert sorted(_matrix(files)) == sorted(CASES)
    assert np.unique(CASES).size == len(CASES)

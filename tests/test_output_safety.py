"""Outputs never destroy the user's data.

* :mod:`divas_engine.output_paths`: the write is temp + fsync + ``os.replace`` with the
  umask's permissions; an injected ``ENOSPC`` / ``EROFS`` at the write, the fsync or the
  rename leaves the previous file byte-identical and no temporary behind, and is one
  :class:`DivasInputError` naming the path.
* An export onto its own input (PLY, ``.splat``, ``.spz``, compressed PLY, SOG) is
  refused and leaves the input byte-identical — also through a hard link.
* ``divas segment`` / ``divas render`` check every output path before loading anything:
  a folder, a missing folder, a device, the input itself → exit 2, one line, no traceback.
* Sessions: a failed save keeps the previous one loadable; a failed autosave warns and
  the session goes on; stale temporaries are removed.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from divas_engine import DivasInputError, cli, load_scene
from divas_engine import output_paths as op
from divas_engine.export import export_selection
from divas_engine.io.splat import SPLAT_DTYPE
from divas_engine.session import store
from divas_engine.synthetic import generate_scene

DATA = Path(__file__).parent / "data"


def _no_temps(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.endswith(op.TEMP_SUFFIX)]


@pytest.fixture(scope="module")
def ribs_files(tmp_path_factory):
    out = tmp_path_factory.mktemp("safety_ribs")
    generate_scene("ribs", out, size=2000, seed=0, grid_resolution=16)
    (out / "prompts.json").write_text(
        json.dumps({"version": 1, "anchors": [{"camera": 0, "clicks": [[10, 10]]}]})
    )
    return out


# ------------------------------------------------------------------ the helper itself
@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_atomic_write_replaces_with_umask_permissions(tmp_path, umask):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    old = os.umask(umask)
    try:
        op.write_bytes_atomic(target, b"new contents")
    finally:
        os.umask(old)
    assert target.read_bytes() == b"new contents"
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    assert _no_temps(tmp_path) == []


def _fail(err):
    def f(*a, **k):
        raise OSError(err, os.strerror(err))

    return f


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EROFS])
@pytest.mark.parametrize("where", ["write", "fsync", "replace"])
def test_injected_oserror_keeps_the_previous_file(tmp_path, monkeypatch, err, where):
    target = tmp_path / "labels.npy"
    np.save(target, np.arange(5))
    before = target.read_bytes()
    if where == "write":
        monkeypatch.setattr(np, "save", _fail(err))
    else:
        monkeypatch.setattr(os, where, _fail(err))
    with pytest.raises(DivasInputError) as ei:
        op.save_npy_atomic(target, np.zeros(1000))
    monkeypatch.undo()
    assert str(target) in str(ei.value) and os.strerror(err) in str(ei.value)
    assert "\n" not in str(ei.value)
    assert target.read_bytes() == before
    assert _no_temps(tmp_path) == []


def test_an_interrupted_writer_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.ply"
    target.write_bytes(b"previous")
    with pytest.raises(KeyboardInterrupt), op.atomic_file(target) as f:
        f.write(b"half")
        raise KeyboardInterrupt
    assert target.read_bytes() == b"previous" and _no_temps(tmp_path) == []


def test_stale_temporaries_of_dead_writers_are_removed(tmp_path):
    target = tmp_path / "s.json"
    dead = tmp_path / f".s.json.999999999-abcd{op.TEMP_SUFFIX}"  # no such pid
    live = tmp_path / f".s.json.1-abcd{op.TEMP_SUFFIX}"  # pid 1 is alive
    other = tmp_path / f".t.json.999999999-abcd{op.TEMP_SUFFIX}"  # another file's
    for p in (dead, live, other):
        p.write_bytes(b"x")
    assert op.remove_stale_temps(target) == 1
    assert not dead.exists() and live.exists() and other.exists()


def test_a_write_removes_a_killed_writers_temporary_of_that_file(tmp_path):
    target = tmp_path / "labels.npy"
    dead = tmp_path / f".labels.npy.999999999-abcd{op.TEMP_SUFFIX}"
    other = tmp_path / f".other.npy.999999999-abcd{op.TEMP_SUFFIX}"
    dead.write_bytes(b"half")
    other.write_bytes(b"half")
    op.save_npy_atomic(target, np.arange(3))
    assert not dead.exists() and other.exists()


@pytest.mark.parametrize(
    "case, problem",
    [
        ("folder", "is a folder"),
        ("missing", "does not exist"),
        ("device", "not a regular file"),
        ("input", "is the input"),
        ("hardlink", "is the input"),
        ("symlink", "is the input"),
    ],
)
def test_preflight(tmp_path, case, problem):
    src = tmp_path / "in.ply"
    src.write_bytes(b"ply")
    path = {
        "folder": tmp_path,
        "missing": tmp_path / "nope" / "out.ply",
        "device": Path("/dev/full"),
        "input": tmp_path / "." / "in.ply",
        "hardlink": tmp_path / "link.ply",
        "symlink": tmp_path / "sym.ply",
    }[case]
    if case == "hardlink":
        os.link(src, path)
    if case == "symlink":
        path.symlink_to(src)
    with pytest.raises(DivasInputError, match=problem) as ei:
        op.check_output_path(path, inputs=[src])
    assert str(path) in str(ei.value)
    assert src.read_bytes() == b"ply"


# ------------------------------------------------------------------ export onto its input
def _splat(path: Path, n: int = 64) -> Path:
    rng = np.random.default_rng(0)
    rec = np.zeros(n, SPLAT_DTYPE)
    rec["pos"] = rng.normal(size=(n, 3))
    rec["scale"] = 0.05
    rec["rgba"] = 200
    rec["rot"] = [255, 128, 128, 128]
    rec.tofile(path)
    return path


def _sources(tmp_path: Path, ribs_files: Path) -> dict[str, Path]:
    shutil.copy(ribs_files / "scene.ply", tmp_path / "scene.ply")
    shutil.copy(DATA / "playcanvas-splats" / "biker.spz", tmp_path / "biker.spz")
    shutil.copy(DATA / "playcanvas-splats" / "guitar.compressed.ply", tmp_path / "g.ply")
    shutil.copytree(DATA / "playcanvas-sog" / "playcanvas-logo", tmp_path / "logo")
    return {
        "ply": tmp_path / "scene.ply",
        "splat": _splat(tmp_path / "s.splat"),
        "spz": tmp_path / "biker.spz",
        "compressed_ply": tmp_path / "g.ply",
        "sog": tmp_path / "logo" / "meta.json",
    }


@pytest.mark.parametrize("fmt", ["ply", "splat", "spz", "compressed_ply", "sog"])
def test_export_onto_its_input_leaves_it_byte_identical(tmp_path, ribs_files, fmt):
    src = _sources(tmp_path, ribs_files)[fmt]
    scene = load_scene(src)
    assert scene.source.format == fmt
    files = sorted(src.parent.rglob("*")) if fmt == "sog" else [src]
    before = {p: p.read_bytes() for p in files if p.is_file()}
    sel = np.zeros(len(scene), bool)
    sel[::3] = True
    targets = [src] + ([src.parent] if fmt == "sog" else [])
    if fmt in ("ply", "splat"):
        link = src.with_name("hard" + src.suffix)
        os.link(src, link)
        targets.append(link)
    for target in targets:
        with pytest.raises(DivasInputError, match="input"):
            export_selection(scene, sel, target)
    assert {p: p.read_bytes() for p in before} == before
    assert _no_temps(src.parent) == []


def test_export_failure_keeps_the_previous_export(tmp_path, ribs_files, monkeypatch):
    scene = load_scene(ribs_files / "scene.ply")
    sel = np.zeros(len(scene), bool)
    sel[:100] = True
    out, lab = tmp_path / "sel.ply", tmp_path / "sel.npy"
    export_selection(scene, sel, out, labels_path=lab)
    before = out.read_bytes(), lab.read_bytes()
    sel[:500] = True
    monkeypatch.setattr(os, "replace", _fail(errno.ENOSPC))
    with pytest.raises(DivasInputError, match="No space left"):
        export_selection(scene, sel, out, labels_path=lab)
    monkeypatch.undo()
    assert (out.read_bytes(), lab.read_bytes()) == before and _no_temps(tmp_path) == []
    assert len(load_scene(out)) == 100


# ------------------------------------------------------------------ the CLI pre-flight
def _forbid_loading(monkeypatch):
    def boom(*a, **k):
        raise AssertionError("loaded the scene before checking the outputs")

    import divas_engine
    import divas_engine.io.load

    monkeypatch.setattr(divas_engine.io.load, "load_scene", boom)
    monkeypatch.setattr(divas_engine, "load_scene", boom)


@pytest.mark.parametrize(
    "flag, value, problem",
    [
        ("--out", "{dir}", "is a folder"),
        ("--out", "{dir}/missing/sel.ply", "does not exist"),
        ("--out", "/dev/full", "not a regular file"),
        ("--out", "{scene}", "is the input"),
        ("--out", "{prompts}", "is the input"),
        ("--labels-out", "{dir}/missing/l.npy", "does not exist"),
        ("--labels-out", "{out}", "same path"),
        ("--session", "{dir}", "is a folder"),
        ("--session", "{scene}", "is the input"),
        ("--report", "{dir}/missing/r.json", "does not exist"),
    ],
)
def test_segment_checks_outputs_before_loading(
    tmp_path, ribs_files, monkeypatch, capsys, flag, value, problem
):
    scene = tmp_path / "scene.ply"
    shutil.copy(ribs_files / "scene.ply", scene)
    before = scene.read_bytes()
    fmt = {
        "dir": tmp_path,
        "scene": scene,
        "prompts": ribs_files / "prompts.json",
        "out": tmp_path / "o.ply",
    }
    args = {"--out": str(tmp_path / "o.ply"), flag: value.format(**fmt)}
    argv = ["segment", str(scene), "--prompts", str(ribs_files / "prompts.json")]
    for k, v in args.items():
        argv += [k, v]
    _forbid_loading(monkeypatch)
    assert cli.main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert problem in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert scene.read_bytes() == before


@pytest.mark.parametrize(
    "case, problem",
    [
        ("parent_is_a_file", "must be a folder"),
        ("png_is_a_folder", "is a folder"),
        ("npz_is_the_input", "is the input"),
    ],
)
def test_render_checks_outputs_before_loading(tmp_path, monkeypatch, capsys, case, problem):
    scene = tmp_path / "grid.npz"  # never loaded: the check comes first
    scene.write_bytes(b"scene")
    (tmp_path / "file.txt").write_text("not a folder")
    (tmp_path / "r.png").mkdir()
    prefix = {
        "parent_is_a_file": tmp_path / "file.txt" / "r",
        "png_is_a_folder": tmp_path / "r",
        "npz_is_the_input": tmp_path / "grid",
    }[case]
    _forbid_loading(monkeypatch)
    rc = cli.main(
        ["render", str(scene), "--orbit", "0,30", "--out", str(prefix), "--device", "cpu"]
    )
    err = capsys.readouterr().err
    assert rc == 2 and problem in err, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert scene.read_bytes() == b"scene"


# ------------------------------------------------------------------ sessions
def test_failed_session_save_keeps_the_previous_save(tmp_path, monkeypatch):
    path = tmp_path / "s.json"
    store.save_state(
        path, {"format": store.SESSION_FORMAT, "version": 1, "n": 1}, {"a": np.ones(3)}
    )
    real = op.write_bytes_atomic
    calls = []

    def fail_on_manifest(p, data):  # the arrays land, the manifest does not
        calls.append(Path(p).name)
        if Path(p) == path:
            raise DivasInputError(p, "cannot write the output: No space left on device")
        return real(p, data)

    monkeypatch.setattr(store, "write_bytes_atomic", fail_on_manifest)
    with pytest.raises(DivasInputError, match="No space"):
        store.save_state(
            path, {"format": store.SESSION_FORMAT, "version": 1, "n": 2}, {"a": np.zeros(3)}
        )
    monkeypatch.undo()
    assert len(calls) == 2  # arrays, then the manifest
    doc, arrays = store.load_state(path)
    assert doc["n"] == 1 and np.array_equal(arrays["a"], np.ones(3))
    # the unreferenced arrays of the failed save are gone; only the pair remains
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s.json", doc["arrays"]["file"]])


def test_session_save_removes_dead_writers_temporaries(tmp_path):
    path = tmp_path / "s.json"
    doc = {"format": store.SESSION_FORMAT, "version": 1}
    dead = [  # a manifest and an arrays file (a hash never saved) of a killed writer
        tmp_path / f".s.json.999999999-ab12{op.TEMP_SUFFIX}",
        tmp_path / f".s.json.0123456789abcdef.npz.999999999-cd34{op.TEMP_SUFFIX}",
    ]
    for p in dead:
        p.write_bytes(b"torn")
    store.save_state(path, doc, {"a": np.ones(2)})
    assert not any(p.exists() for p in dead)
    assert len(list(tmp_path.iterdir())) == 2


def test_legacy_session_layout_loads_and_is_migrated(tmp_path):
    """A session in the legacy layout (arrays in ``<path>.npz``) loads; the next save
    writes the content-addressed file and removes the legacy one and its temporaries."""
    import hashlib
    import io

    path = tmp_path / "s.json"
    buf = io.BytesIO()
    np.savez_compressed(buf, a=np.arange(4))
    (tmp_path / "s.json.npz").write_bytes(buf.getvalue())
    doc = {
        "format": store.SESSION_FORMAT,
        "version": 1,
        "arrays": {
            "file": "s.json.npz",
            "sha256": hashlib.sha256(buf.getvalue()).hexdigest(),
            "keys": ["a"],
        },
    }
    path.write_text(json.dumps(doc))
    (tmp_path / ".s.json.npz.ab12cd34.tmp").write_bytes(b"torn")  # old mkstemp leftover
    d, arrays = store.load_state(path)
    assert np.array_equal(arrays["a"], np.arange(4))
    assert not (tmp_path / ".s.json.npz.ab12cd34.tmp").exists()
    store.save_state(path, {k: v for k, v in d.items() if k != "arrays"}, arrays)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) == 2 and "s.json.npz" not in names


def test_failed_autosave_warns_and_the_session_goes_on(tmp_path, ribs_files, monkeypatch):
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    scene = load_scene(ribs_files / "scene.ply")
    from divas_engine.io.cameras import load_cameras

    cams = load_cameras(ribs_files / "cameras.json")
    gt = np.load(ribs_files / "labels.npy")
    auto = tmp_path / "auto.json"
    s = Session.open(
        scene,
        cams,
        SessionConfig(render_scale=0.25, autosave=str(auto)),
        OracleSegmenter(),
        "cpu",
        anchors=cams[:2],
        gt_values=gt,
        render_anchors=False,
    )
    assert auto.exists() and s.autosave_error is None  # saved at open: the anchors
    saved = auto.read_bytes()
    click = json.loads((ribs_files / "scene.json").read_text())["clicks"][0]
    cam = next(c for c in cams if c.name in click["visible_in"])
    s.add_anchor(cam)
    saved = auto.read_bytes()
    monkeypatch.setattr(os, "fsync", _fail(errno.ENOSPC))
    uv, _ = s.anchors[-1].camera.project(np.array([click["xyz"]]))
    with pytest.warns(RuntimeWarning, match="autosave failed"):
        v = s.click(len(s.anchors) - 1, uv[0])
    assert s.autosave_error and "No space" in s.autosave_error
    assert auto.read_bytes() == saved and _no_temps(tmp_path) == []
    monkeypatch.undo()
    s.accept(v)  # the work goes on; the next autosave lands
    assert s.autosave_error is None
    s2 = Session.load(auto, scene, device="cpu")
    assert s2.replay_matches and np.array_equal(s2.selection, s.selection)
    s.close()
    s2.close()

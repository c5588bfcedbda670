"""Each malformed-input class the fuzzing found, built by hand, ends
in one DivasInputError naming the file (or is dropped and counted), within bounded
memory; FIFOs are refused before they are opened."""

from __future__ import annotations

import gzip
import json
import os
import struct
import zipfile

import numpy as np
import pytest

from divas_engine import Camera, DivasInputError
from divas_engine.io.cameras import load_cameras, save_cameras
from divas_engine.io.density_grid import write_density_grid
from divas_engine.io.json_file import read_json
from divas_engine.io.limits import inflate_budget, load_limits
from divas_engine.io.load import load_scene
from divas_engine.io.ply import surfel_rows, write_ply_rows
from divas_engine.io.splat import SPLAT_DTYPE
from divas_engine.scene import DensityGrid
from divas_engine.session.prompts import load_prompts

from .fuzz_cases import _tiny_surfel_scene


def _raises(path, fn, *words):
    with pytest.raises(DivasInputError) as e:
        fn(path)
    msg = str(e.value)
    assert str(path) in msg or os.path.basename(str(path)) in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


# ----------------------------------------------------------------------------- PLY
def _ply(tmp_path, header_edit, n=5):
    p = tmp_path / "s.ply"
    write_ply_rows(p, {"vertex": surfel_rows(_tiny_surfel_scene(n, 0, 0))})
    data = p.read_bytes()
    end = data.index(b"end_header\n")
    lines = data[:end].decode().split("\n")[:-1]
    lines = header_edit(lines)
    p.write_bytes(("\n".join(lines) + "\nend_header\n").encode() + data[end + 11 :])
    return p


def test_ply_duplicate_property_and_element(tmp_path):
    p = _ply(tmp_path, lambda ls: ls[:4] + [ls[3]] + ls[4:])
    _raises(p, load_scene, "malformed PLY header")
    p = _ply(tmp_path, lambda ls: ls + ["element vertex 0", "property float x"])
    _raises(p, load_scene)


def test_ply_negative_and_huge_counts(tmp_path):
    p = _ply(
        tmp_path, lambda ls: [ln.replace("element vertex 5", "element vertex -5") for ln in ls]
    )
    _raises(p, load_scene)
    p = _ply(
        tmp_path,
        lambda ls: [ln.replace("element vertex 5", f"element vertex {10**30}") for ln in ls],
    )
    _raises(p, load_scene)


def test_ply_list_property_where_a_scalar_is_expected(tmp_path):
    p = _ply(
        tmp_path,
        lambda ls: [ln.replace("property float x", "property list uchar float x") for ln in ls],
    )
    _raises(p, load_scene)


def test_ascii_ply_claiming_a_billion_rows_is_refused_before_parsing(tmp_path):
    p = tmp_path / "a.ply"
    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1"]
    props += ["rot_0", "rot_1", "rot_2", "rot_3"]
    head = ["ply", "format ascii 1.0", "element vertex 1000000000"]
    head += [f"property float {q}" for q in props] + ["end_header", " ".join(["0.5"] * 13)]
    p.write_text("\n".join(head) + "\n")
    _raises(p, load_scene, "1000000000 rows")


# ----------------------------------------------------------------------------- density npz
def _grid_file(tmp_path, **arrays):
    p = tmp_path / "g.npz"
    np.savez(p, **arrays)
    return p


def test_npz_structured_dtype_and_bad_header(tmp_path):
    aabb = np.array([[0, 0, 0], [1, 1, 1.0]])
    rec = np.zeros((2, 2, 2), dtype=[("a", "f4"), ("b", "i4")])
    _raises(_grid_file(tmp_path, density=rec, aabb=aabb), load_scene, "not a plain numeric")
    p = tmp_path / "h.npz"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr(
            "density.npy", b"\x93NUMPY\x01\x00\xff\x00" + b"{'descr': '<f4', (((" + b" " * 40
        )
        z.writestr("aabb.npy", b"")
    _raises(p, load_scene, "bad .npy header")


def test_npz_huge_declared_shape_is_refused_before_allocation(tmp_path):
    p = tmp_path / "big.npz"
    head = "{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000, 100000), }"
    head = head.ljust(118) + "\n"
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(head)) + head.encode() + b"\0" * 64
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("density.npy", npy)
        z.writestr("aabb.npy", npy)
    _raises(p, load_scene, "needs")


def test_npz_encrypted_member_and_bad_zlib(tmp_path):
    g = DensityGrid(np.ones((3, 3, 3), np.float32), np.array([[0, 0, 0], [1, 1, 1.0]]), None, None)
    p = tmp_path / "g.npz"
    write_density_grid(p, g)
    data = bytearray(p.read_bytes())
    i = data.index(b"PK\x01\x02")  # central directory: general purpose flags at +8
    data[i + 8] |= 1
    p.write_bytes(bytes(data))
    _raises(p, load_scene)
    write_density_grid(p, g)
    data = bytearray(p.read_bytes())
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("density.npy")
    h = info.header_offset  # local header: 30 bytes, the name, the extra field, then data
    n_name, n_extra = struct.unpack_from("<HH", data, h + 26)
    j = h + 30 + n_name + n_extra
    data[j : j + 8] = b"\xff" * 8  # the deflate stream's first bytes
    p.write_bytes(bytes(data))
    _raises(p, load_scene)


def test_npz_declared_sizes_are_bounded_by_the_load_limits(tmp_path):
    dens = np.zeros((64, 64, 64), np.float32)
    dens[0, 0, 0] = 1  # compresses to almost nothing
    p = tmp_path / "z.npz"
    write_density_grid(p, DensityGrid(dens, np.array([[0, 0, 0], [1, 1, 1.0]]), None, None))
    assert len(load_scene(p).density.ravel()) == 64**3
    with load_limits(min_inflate_bytes=1 << 16, max_inflate_ratio=4):
        assert inflate_budget(p.stat().st_size) == 1 << 16
        _raises(p, load_scene, "limit")


# ----------------------------------------------------------------------------- splat / spz / cply
def test_splat_zero_rotation_and_nonpositive_scales_are_dropped_and_counted(tmp_path):
    rows = np.zeros(6, SPLAT_DTYPE)
    rows["pos"] = np.arange(18).reshape(6, 3)
    rows["scale"] = 0.1
    rows["rgba"] = 200
    rows["rot"] = [255, 128, 128, 128]
    rows["rot"][1] = 128  # zero quaternion
    rows["scale"][2] = [0.0, 0.1, 0.1]
    rows["scale"][3] = [-0.1, 0.1, 0.1]
    p = tmp_path / "s.splat"
    rows.tofile(p)
    s = load_scene(p)
    assert len(s) == 3 and s.source.dropped_nonfinite == 3
    assert s.source.kept_rows.tolist() == [0, 4, 5]


def test_spz_gzip_bomb_is_bounded(tmp_path):
    payload = struct.pack("<IIIBBBB", 0x5053474E, 2, 10, 0, 12, 0, 0) + b"\0" * (64 << 20)
    p = tmp_path / "bomb.spz"
    p.write_bytes(gzip.compress(payload, compresslevel=9))
    assert p.stat().st_size < 200_000
    with load_limits(min_inflate_bytes=8 << 20):
        _raises(p, load_scene, "inflates past")


def test_spz_v4_declared_points_beyond_the_limit(tmp_path):
    head = struct.pack("<IIIBBBBI", 0x5053474E, 4, 2**32 - 1, 0, 12, 0, 5, 32) + b"\0" * 12
    p = tmp_path / "v4.spz"
    p.write_bytes(head + b"\0" * (16 * 5 + 100))
    _raises(p, load_scene)


def test_compressed_ply_extreme_colour_bounds_drop_rows(real_data, tmp_path):
    from divas_engine.io.compressed_ply import write_compressed_ply_subset
    from divas_engine.io.ply import iter_vertex_chunks, read_ply_header

    src = load_scene(real_data / "playcanvas-splats" / "guitar.compressed.ply")
    p = tmp_path / "c.compressed.ply"
    write_compressed_ply_subset(src.source, np.arange(512), p)
    lay = read_ply_header(p)
    assert load_scene(p).source.dropped_nonfinite == 0
    # chunk 0's colour bounds become ±3.4e38: its 256 rows decode to ±inf SH
    off = lay.data_offset
    chunk = lay.element("chunk")
    dt = np.dtype(chunk.dtype(lay.byte_order))
    rows = np.fromfile(p, dt, count=chunk.count, offset=off)
    if "min_r" not in dt.names:
        pytest.skip("subset has no colour bounds")
    rows["min_r"][0], rows["max_r"][0] = -3.4e38, 3.4e38
    data = bytearray(p.read_bytes())
    data[off : off + rows.nbytes] = rows.tobytes()
    p.write_bytes(bytes(data))
    del iter_vertex_chunks
    s = load_scene(p)
    assert np.isfinite(s.sh).all()
    assert s.source.dropped_nonfinite > 0 and len(s) + s.source.dropped_nonfinite == 512


# ----------------------------------------------------------------------------- JSON inputs
def test_json_deep_nesting_and_huge_integers(tmp_path):
    p = tmp_path / "cameras.json"
    p.write_text("[" * 100_000 + "]" * 100_000)
    _raises(p, lambda q: read_json(q, "camera file"), "nested")
    p.write_text("[" + "9" * 5000 + "]")  # beyond int max_str_digits (4300)
    _raises(p, lambda q: read_json(q, "camera file"))


def _cams():
    return [Camera.look_at([0, 0, 3], [0, 0, 0], [0, -1, 0], width=64, height=48, fx=60.0)]


@pytest.mark.parametrize(
    "key, value",
    [
        ("width", "1e400"),
        ("width", str(2**63)),
        ("width", "200000"),
        ("fx", "1e300"),
        ("fx", "Infinity"),
        ("cx", "NaN"),
        ("cy", "-Infinity"),
        ("height", "0"),
    ],
)
def test_cameras_json_bad_intrinsics(tmp_path, key, value):
    p = save_cameras(tmp_path / "cameras.json", _cams(), "cameras_json")
    doc = json.loads(p.read_text())
    doc[0][key] = "@@"
    p.write_text(json.dumps(doc).replace('"@@"', value))
    _raises(p, load_cameras, "camera entry 0")


def test_transforms_json_long_file_path_and_huge_image_header(tmp_path):
    p = save_cameras(tmp_path / "transforms.json", _cams(), "transforms_json")
    doc = json.loads(p.read_text())
    fr = doc["frames"][0]
    for k in ("w", "h"):
        fr.pop(k, None)
        doc.pop(k, None)
    fr["file_path"] = "x" * 300
    p.write_text(json.dumps(doc))
    _raises(p, load_cameras, "frame 0")
    fr["file_path"] = "big.png"  # a PNG header declaring 100000 x 100000 pixels
    png = (
        b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + struct.pack(">II", 100000, 100000)
    )
    (tmp_path / "big.png").write_bytes(png + b"\x08\x02\0\0\0" + b"\0" * 16)
    p.write_text(json.dumps(doc))
    _raises(p, load_cameras, "frame 0", "100000")


def test_prompts_non_ascii_digit_key_and_click_cap(tmp_path):
    cam = _cams()[0]
    doc = {"version": 1, "anchors": [{"camera": cam.to_dict(), "clicks": [{"xy": [3, 4]}]}]}
    doc["centroid_prompts"] = {"\u0663:0": [{"xy": [1, 1]}]}
    p = tmp_path / "prompts.json"
    p.write_text(json.dumps(doc))
    _raises(p, load_prompts, "anchor:click")
    doc["centroid_prompts"] = {}
    doc["anchors"][0]["clicks"] = [{"xy": [3, 4]}] * 50
    p.write_text(json.dumps(doc))
    assert len(load_prompts(p).anchors[0].clicks) == 50
    with load_limits(max_clicks=49):
        _raises(p, load_prompts, "50 clicks")


# ----------------------------------------------------------------------------- special files
@pytest.mark.parametrize("loader", [load_scene, load_cameras, load_prompts])
def test_fifo_is_refused_without_opening(tmp_path, loader):
    f = tmp_path / ("pipe.json" if loader is not load_scene else "pipe.ply")
    os.mkfifo(f)  # opening it for reading would block forever
    _raises(f, loader)


def test_device_is_refused():
    _raises("/dev/zero", load_scene, "device")


def test_sane_rows_flags_exactly_the_unusable_rows():
    from divas_engine.io.gaussians import sane_rows

    rng = np.random.default_rng(0)
    n = 20
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    means = rng.normal(size=(n, 3)).astype(np.float32)
    scales = np.full((n, 2), 0.1, np.float32)
    opac = np.full(n, 0.5, np.float32)
    sh = rng.normal(size=(n, 4, 3)).astype(np.float32)
    sh[5, 3, 1], sh[6, 3, 1], means[7, 0] = np.inf, np.nan, -np.inf
    q[8] = 0  # zero quaternion
    scales[9, 1], scales[10, 0] = 0.0, -1.0
    opac[11], opac[12] = np.nan, 1.5
    sh[13, 0, 0] = sh[13, 1, 0] = 3.4e38  # huge but finite: kept
    ok = sane_rows((means, q, scales, opac, sh))
    assert np.flatnonzero(~ok).tolist() == [5, 6, 7, 8, 9, 10, 11, 12]

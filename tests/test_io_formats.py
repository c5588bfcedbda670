"""Decoders and subset writers for compressed PLY, ``.splat`` and ``.spz``.

Real data (read-only, described in ``tests/data/README.md``):

* ``playcanvas-splats/biker.compressed.ply`` (152,746 Gaussians, 597 chunks),
  ``guitar.compressed.ply`` (90,854, 355 chunks) and ``biker.spz`` (SPZ
  version 4, 152,746 points) come from playcanvas/engine @ 0aaef5e :
  ``examples/assets/splats/`` (MIT licence, ``LICENSE`` beside them).

Each real file is checked against an independent per-row decoder written here
from the format definitions (``struct`` and integer bit operations on a handful
of rows, no code shared with the loaders). ``.splat``, SPZ v2/v3 and
SH-carrying compressed PLYs have no shared sample, so those tests build small
files from known values.
"""

from __future__ import annotations

import gzip
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from divas_engine.errors import DivasInputError
from divas_engine.io.compressed_ply import (
    decode_compressed_ply_rows,
    is_compressed_ply,
    read_compressed_ply,
    write_compressed_ply_subset,
)
from divas_engine.io.ply import read_ply_header, write_ply_rows
from divas_engine.io.splat import read_splat, write_splat_subset
from divas_engine.io.spz import read_spz, write_spz_subset
from divas_engine.scene import SH_C0

DATA = Path(__file__).resolve().parent / "data"
PC = DATA / "playcanvas-splats"
BIKER_CPLY = PC / "biker.compressed.ply"
GUITAR_CPLY = PC / "guitar.compressed.ply"
BIKER_SPZ = PC / "biker.spz"


# ---------------------------------------------------------------- helpers ----


def _quat_to_mat(w, x, y, z):
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _check_surfel(scene, i, quat_wxyz, scales3, tol=1e-5):
    """Scene row i is the 3D Gaussian (quat, linear scales) flattened to a surfel."""
    order = sorted(range(3), key=lambda a: -scales3[a])
    s = [scales3[a] for a in order]
    assert scene.scales[i] == pytest.approx([s[0], s[1]], rel=1e-5)
    assert scene.scale_n[i] == pytest.approx(s[2], rel=1e-5)  # the dropped axis, kept
    if s[1] > s[2] * 1.001:  # the dropped axis is unambiguous
        normal = _quat_to_mat(*quat_wxyz)[:, order[2]]
        assert abs(float(np.dot(scene.normals()[i], normal))) > 1 - tol


def _ply_sections(path: Path):
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    elements = []  # (name, count, [property lines])
    for line in data[:end].decode("ascii").splitlines():
        parts = line.split()
        if parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            elements[-1][2].append(parts[2])
    return data, end, elements


def _unorm(v, shift, bits):
    m = (1 << bits) - 1
    return ((v >> shift) & m) / m


def _cply_row_by_hand(path: Path, i: int) -> dict:
    """One compressed-PLY row decoded straight from the bytes, per the format definition."""
    data, off, els = _ply_sections(path)
    (cn, cc, cprops), (vn, _vc, _) = els[0], els[1]
    assert (cn, vn) == ("chunk", "vertex")
    nc = len(cprops)
    ch = struct.unpack_from(f"<{nc}f", data, off + (i // 256) * 4 * nc)
    pp, pr, ps, pc = struct.unpack_from("<4I", data, off + cc * 4 * nc + 16 * i)

    def lerp(a, b, t):
        return a * (1 - t) + b * t

    t = (_unorm(pp, 21, 11), _unorm(pp, 11, 10), _unorm(pp, 0, 11))
    pos = [lerp(ch[a], ch[a + 3], t[a]) for a in range(3)]
    t = (_unorm(ps, 21, 11), _unorm(ps, 11, 10), _unorm(ps, 0, 11))
    log_s = [lerp(ch[6 + a], ch[9 + a], t[a]) for a in range(3)]
    rgb = [_unorm(pc, 24, 8), _unorm(pc, 16, 8), _unorm(pc, 8, 8)]
    if nc == 18:
        rgb = [lerp(ch[12 + a], ch[15 + a], rgb[a]) for a in range(3)]
    largest = pr >> 30
    smalls = [
        (_unorm(pr, 20, 10) - 0.5) * math.sqrt(2),
        (_unorm(pr, 10, 10) - 0.5) * math.sqrt(2),
        (_unorm(pr, 0, 10) - 0.5) * math.sqrt(2),
    ]
    q = [0.0] * 4  # rot_0..3 = w, x, y, z
    for idx, v in zip([j for j in range(4) if j != largest], smalls):
        q[idx] = v
    q[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in smalls)))
    return {
        "pos": pos,
        "log_scale": log_s,
        "rgb": rgb,
        "alpha": (pc & 0xFF) / 255,
        "quat": q,
        "words": (pp, pr, ps, pc),
    }


def _spz_v4_by_hand(path: Path) -> dict:
    """Header, table of contents and decompressed columns of an SPZ v4 file."""
    import zstandard

    data = path.read_bytes()
    magic, version, n, deg, frac, flags, n_streams, toc = struct.unpack_from("<4sIIBBBBI", data, 0)
    assert magic == b"NGSP"
    off = toc + 16 * n_streams
    cols = []
    for s in range(n_streams):
        csize, usize = struct.unpack_from("<QQ", data, toc + 16 * s)
        raw = zstandard.ZstdDecompressor().decompress(
            data[off : off + csize], max_output_size=usize
        )
        assert len(raw) == usize
        cols.append(raw)
        off += csize
    assert off == len(data)
    return {
        "version": version,
        "n": n,
        "deg": deg,
        "frac": frac,
        "flags": flags,
        "n_streams": n_streams,
        "toc": toc,
        "cols": cols,
    }


def _spz_row_by_hand(h: dict, i: int) -> dict:
    """One SPZ v3/v4 point in SPZ's own RUB frame, quaternion (x, y, z, w)."""
    pos_b, alpha_b, col_b, scale_b, rot_b = h["cols"][:5]
    pos = [
        int.from_bytes(pos_b[9 * i + 3 * a : 9 * i + 3 * a + 3], "little", signed=True)
        / (1 << h["frac"])
        for a in range(3)
    ]
    word = int.from_bytes(rot_b[4 * i : 4 * i + 4], "little")
    largest = word >> 30
    q = [0.0] * 4
    rest = word
    for j in (3, 2, 1, 0):  # the last component packed sits in the lowest bits
        if j == largest:
            continue
        mag, neg = rest & 0x1FF, (rest >> 9) & 1
        rest >>= 10
        q[j] = (-1 if neg else 1) * math.sqrt(0.5) * mag / 511
    q[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in q)))
    return {
        "pos": pos,
        "alpha": alpha_b[i] / 255,
        "f_dc": [(col_b[3 * i + c] / 255 - 0.5) / 0.15 for c in range(3)],
        "log_scale": [scale_b[3 * i + a] / 16 - 10 for a in range(3)],
        "quat_xyzw": q,
    }


# ------------------------------------------------------- compressed PLY ----


@pytest.fixture(scope="module")
def biker_cply():
    return read_compressed_ply(BIKER_CPLY, read_ply_header(BIKER_CPLY))


@pytest.fixture(scope="module")
def biker_spz():
    return read_spz(BIKER_SPZ)


@pytest.mark.parametrize(
    "path,count,chunks", [(BIKER_CPLY, 152_746, 597), (GUITAR_CPLY, 90_854, 355)]
)
def test_compressed_ply_counts(path, count, chunks):
    layout = read_ply_header(path)
    assert is_compressed_ply(layout)
    assert layout.element("chunk").count == chunks and layout.vertex.count == count
    scene = read_compressed_ply(path, layout)
    assert len(scene) == count and scene.sh_degree == 0 and scene.kind == "3dgs"
    assert scene.source.format == "compressed_ply" and scene.source.num_rows == count
    assert scene.source.dropped_nonfinite == 0


def test_standard_ply_is_not_compressed():
    assert not is_compressed_ply(read_ply_header(DATA / "gaussiansplats3d-lod" / "lod3_tile_0.ply"))


def test_biker_compressed_ply_rows_by_hand(biker_cply):
    scene = biker_cply
    assert len(scene) == 152_746 and scene.source.format == "compressed_ply"
    np.testing.assert_array_equal(scene.source.kept_rows, np.arange(152_746))
    rows = [0, 1, 255, 256, 4097, 77_777, 152_745]
    dec = decode_compressed_ply_rows(BIKER_CPLY, np.array(rows))
    for j, i in enumerate(rows):
        h = _cply_row_by_hand(BIKER_CPLY, i)
        np.testing.assert_allclose(scene.means[i], h["pos"], rtol=0, atol=1e-6)
        assert scene.opacities[i] == pytest.approx(h["alpha"], abs=1e-7)
        dc = [(c - 0.5) / SH_C0 for c in h["rgb"]]
        np.testing.assert_allclose(scene.sh[i, 0], dc, rtol=0, atol=1e-5)
        _check_surfel(scene, i, h["quat"], [math.exp(v) for v in h["log_scale"]])
        np.testing.assert_allclose(dec["pos"][j], h["pos"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(dec["log_scale"][j], h["log_scale"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(dec["quat"][j], h["quat"], rtol=0, atol=1e-12)


def test_guitar_compressed_ply_rows_by_hand():
    scene = read_compressed_ply(GUITAR_CPLY, read_ply_header(GUITAR_CPLY))
    for i in (0, 300, 90_853):
        h = _cply_row_by_hand(GUITAR_CPLY, i)
        np.testing.assert_allclose(scene.means[i], h["pos"], rtol=0, atol=1e-6)
        assert scene.opacities[i] == pytest.approx(h["alpha"], abs=1e-7)
        _check_surfel(scene, i, h["quat"], [math.exp(v) for v in h["log_scale"]])


def _synthetic_cply(path: Path, n: int, n_rest: int, color_bounds: bool, seed: int = 0):
    """A compressed PLY with random packed words, sane chunk bounds and an ``sh`` element."""
    rng = np.random.default_rng(seed)
    c = -(-n // 256)
    names = [
        "min_x",
        "min_y",
        "min_z",
        "max_x",
        "max_y",
        "max_z",
        "min_scale_x",
        "min_scale_y",
        "min_scale_z",
        "max_scale_x",
        "max_scale_y",
        "max_scale_z",
    ]
    if color_bounds:
        names += ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
    chunk = np.zeros(c, dtype=[(nm, "<f4") for nm in names])
    lo = rng.uniform(-5, 0, (c, 3))
    for a, ax in enumerate("xyz"):
        chunk[f"min_{ax}"], chunk[f"max_{ax}"] = lo[:, a], lo[:, a] + rng.uniform(0.1, 3, c)
        chunk[f"min_scale_{ax}"] = rng.uniform(-9, -5, c)
        chunk[f"max_scale_{ax}"] = rng.uniform(-4, -1, c)
    if color_bounds:
        for ch in "rgb":
            chunk[f"min_{ch}"], chunk[f"max_{ch}"] = (
                rng.uniform(-0.2, 0.3, c),
                rng.uniform(0.6, 1.2, c),
            )
    vert = np.zeros(
        n,
        dtype=[
            (nm, "<u4")
            for nm in ("packed_position", "packed_rotation", "packed_scale", "packed_color")
        ],
    )
    for nm in vert.dtype.names:
        vert[nm] = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    elements = {"chunk": chunk, "vertex": vert}
    if n_rest:
        sh = np.zeros(n, dtype=[(f"f_rest_{k}", "u1") for k in range(n_rest)])
        for k in range(n_rest):
            sh[f"f_rest_{k}"] = rng.integers(0, 256, n)
        sh[0]["f_rest_0"], sh[1]["f_rest_0"] = 0, 255
        elements["sh"] = sh
    write_ply_rows(path, elements)
    return elements


def test_compressed_ply_sh_element(tmp_path):
    p = tmp_path / "sh.compressed.ply"
    els = _synthetic_cply(p, 600, 24, True)
    scene = read_compressed_ply(p)
    assert scene.sh_degree == 2 and len(scene) == 600 and scene.sh.shape == (600, 9, 3)

    def deq(b):  # splat-transform's reader: bucket centres, ends pinned to +-4
        return -4.0 if b == 0 else 4.0 if b == 255 else ((b + 0.5) / 256 - 0.5) * 8

    sh = els["sh"]
    for i in (0, 1, 7, 599):
        for ch in range(3):
            for k in range(8):  # f_rest is channel-major: f_rest[ch*8 + k] is coeff k+1
                assert scene.sh[i, k + 1, ch] == pytest.approx(
                    deq(int(sh[i][f"f_rest_{ch * 8 + k}"]))
                )
        h = _cply_row_by_hand(p, i)
        np.testing.assert_allclose(scene.means[i], h["pos"], rtol=0, atol=1e-5)
        np.testing.assert_allclose(scene.sh[i, 0], [(c - 0.5) / SH_C0 for c in h["rgb"]], atol=1e-5)


def _assert_reencoded(src_path, rows, out_path):
    """The subset decodes to the source rows within half a step of its fresh chunk ranges."""
    a = decode_compressed_ply_rows(src_path, rows)
    b = decode_compressed_ply_rows(out_path)
    data, off, els = _ply_sections(out_path)
    (_, cc, cprops) = els[0]
    chunk = np.frombuffer(data, "<f4", cc * len(cprops), off).reshape(cc, len(cprops))
    ci = np.arange(len(rows)) // 256
    rng = (chunk[:, 3:6] - chunk[:, 0:3])[ci].astype(np.float64)
    steps = np.array([2047, 1023, 2047])
    tol = lambda v: 0.5 * rng / steps + 1e-6 * (1 + np.abs(v))  # noqa: E731
    assert np.all(np.abs(b["pos"] - a["pos"]) <= tol(a["pos"]))
    srng = (chunk[:, 9:12] - chunk[:, 6:9])[ci].astype(np.float64)
    assert np.all(np.abs(b["log_scale"] - a["log_scale"]) <= 0.5 * srng / steps + 1e-5)
    if len(cprops) == 18:
        crng = (chunk[:, 15:18] - chunk[:, 12:15])[ci].astype(np.float64)
        assert np.all(np.abs(b["rgb"] - a["rgb"]) <= 0.5 * crng / 255 + 1e-6)
    else:
        np.testing.assert_array_equal(b["rgb"], a["rgb"])
    np.testing.assert_array_equal(b["alpha"], a["alpha"])
    np.testing.assert_array_equal(b["quat"], a["quat"])
    np.testing.assert_array_equal(b["f_rest"], a["f_rest"])


@pytest.mark.parametrize("color_bounds,n_rest", [(True, 45), (False, 9)])
def test_compressed_ply_subset_synthetic(tmp_path, color_bounds, n_rest):
    src = tmp_path / "src.compressed.ply"
    _synthetic_cply(src, 1000, n_rest, color_bounds, seed=3)
    scene = read_compressed_ply(src)
    rows = np.random.default_rng(1).choice(1000, 333, replace=False)  # any order
    out = tmp_path / "sub.compressed.ply"
    write_compressed_ply_subset(scene.source, rows, out)
    layout = read_ply_header(out)
    assert is_compressed_ply(layout) and layout.element("chunk").count == 2
    assert len(layout.element("chunk").properties) == (18 if color_bounds else 12)
    _assert_reencoded(src, rows, out)
    sub = read_compressed_ply(out)
    np.testing.assert_array_equal(sub.opacities, scene.opacities[rows])
    np.testing.assert_array_equal(sub.sh[:, 1:], scene.sh[rows, 1:])


def test_compressed_ply_subset_biker(tmp_path, biker_cply):
    rows = np.sort(np.random.default_rng(7).choice(152_746, 20_000, replace=False))
    out = tmp_path / "biker_sub.compressed.ply"
    write_compressed_ply_subset(biker_cply.source, rows, out)
    _assert_reencoded(BIKER_CPLY, rows, out)
    sub = read_compressed_ply(out)
    assert len(sub) == 20_000 and sub.source.num_rows == 20_000
    np.testing.assert_array_equal(sub.opacities, biker_cply.opacities[rows])
    # end to end: positions move by at most half a step of the (smaller) fresh ranges
    step = np.array([2047, 1023, 2047])
    orig_range = np.ptp(biker_cply.means, axis=0) / step
    assert np.all(np.abs(sub.means - biker_cply.means[rows]) <= orig_range)


# ------------------------------------------------------------------ SPZ ----


def test_biker_spz_rows_by_hand(biker_spz):
    scene = biker_spz
    h = _spz_v4_by_hand(BIKER_SPZ)
    assert h["version"] == 4 and h["n"] == 152_746 and h["deg"] == 0 and h["n_streams"] == 5
    assert len(scene) == 152_746 and scene.source.format == "spz" and scene.sh_degree == 0
    assert scene.source.dropped_nonfinite == 0
    assert scene.extras == {"spz_version": 4, "antialiased": False}
    for i in (0, 1, 1000, 99_999, 152_745):
        r = _spz_row_by_hand(h, i)
        x, y, z = r["pos"]
        np.testing.assert_allclose(scene.means[i], [x, -y, -z], rtol=0, atol=1e-6)  # RUB -> RDF
        assert scene.opacities[i] == pytest.approx(r["alpha"], abs=1e-7)
        np.testing.assert_allclose(scene.sh[i, 0], r["f_dc"], rtol=0, atol=1e-5)
        qx, qy, qz, qw = r["quat_xyzw"]
        _check_surfel(scene, i, (qw, qx, -qy, -qz), [math.exp(v) for v in r["log_scale"]])


def test_biker_compressed_ply_and_spz_agree(biker_cply, biker_spz):
    """Same scene, same point order; differences are SPZ's quantisation of the PLY values."""
    c, s = biker_cply, biker_spz
    assert len(c) == len(s) == 152_746
    d = np.abs(s.means - c.means)
    assert d.max() <= 0.5 / 4096 + 1e-6  # SPZ's 12 fractional bits round the decoded PLY value
    # the order really is the same: nearest neighbours agree for (almost) every point
    _, nn = cKDTree(c.means).query(s.means)
    assert np.mean(nn == np.arange(len(s))) > 0.99
    assert np.all(
        np.linalg.norm(c.means[nn] - s.means, axis=1) <= d.max(axis=1) * math.sqrt(3) + 1e-7
    )
    assert np.abs(s.opacities - c.opacities).max() <= 0.5 / 255 + 1e-7
    assert np.abs(s.sh[:, 0] - c.sh[:, 0]).max() <= 0.5 / (255 * 0.15) + 1e-5
    # log-scales: SPZ stores (s + 10) * 16 in a byte, so it clamps to [-10, 5.9375]
    ls_c = np.clip(np.log(c.scales.astype(np.float64)), -10, 255 / 16 - 10)
    assert np.abs(np.log(s.scales.astype(np.float64)) - ls_c).max() <= 1 / 32 + 1e-4
    same_axes = np.abs(np.sum(s.normals() * c.normals(), axis=1)) > 0.9999
    assert np.mean(same_axes) > 0.99


def _spz_payload(
    version: int, n: int, deg: int, cols: dict, flags: int = 0, ext: bytes = b""
) -> bytes:
    head = struct.pack("<4sIIBBBB", b"NGSP", version, n, deg, 12, flags, 0)
    order = ("positions", "alphas", "colors", "scales", "rotations", "sh")
    return head + ext + b"".join(cols[k] for k in order)


def _fixed24(v: float) -> bytes:
    return (round(v * 4096) & 0xFFFFFF).to_bytes(3, "little")


def _smallest_three(q_xyzw) -> bytes:
    q = np.asarray(q_xyzw, float) / np.linalg.norm(q_xyzw)
    big = int(np.argmax(np.abs(q)))
    if q[big] < 0:
        q = -q
    word = big
    for j in range(4):
        if j != big:
            word = (
                (word << 10) | (int(q[j] < 0) << 9) | int(round(511 * abs(q[j]) / math.sqrt(0.5)))
            )
    return word.to_bytes(4, "little")


def _synthetic_spz_cols(version: int):
    q0 = (0.1, -0.2, 0.3, 0.9)  # x, y, z, w in SPZ's RUB frame
    q1 = (0.0, 0.6, 0.0, 0.8)
    if version >= 3:
        rot = _smallest_three(q0) + _smallest_three(q1)
    else:

        def first3(q):
            q = np.asarray(q) / np.linalg.norm(q)
            return bytes(int(round(v * 127.5 + 127.5)) for v in q[:3])

        rot = first3(q0) + first3(q1)
    sh = bytes([10, 20, 30, 128, 128, 250, 200, 100, 0] + [128] * 9)  # deg 1, [coeff][channel]
    cols = {
        "positions": _fixed24(1.0)
        + _fixed24(2.0)
        + _fixed24(-3.0)
        + _fixed24(-0.5)
        + _fixed24(0.25)
        + _fixed24(100.0),
        "alphas": bytes([200, 5]),
        "colors": bytes([100, 150, 200, 0, 255, 128]),
        "scales": bytes([160, 144, 128, 0, 255, 100]),
        "rotations": rot,
        "sh": sh,
    }
    return cols, (q0, q1)


@pytest.mark.parametrize("version", [2, 3])
def test_spz_gzip_versions_synthetic(tmp_path, version):
    cols, (q0, _) = _synthetic_spz_cols(version)
    p = tmp_path / f"v{version}.spz"
    p.write_bytes(gzip.compress(_spz_payload(version, 2, 1, cols, flags=1)))
    s = read_spz(p)
    assert len(s) == 2 and s.sh_degree == 1 and s.extras["antialiased"] is True
    np.testing.assert_allclose(s.means, [[1, -2, 3], [-0.5, -0.25, -100]], atol=1e-6)  # RUB -> RDF
    np.testing.assert_allclose(s.opacities, [200 / 255, 5 / 255], atol=1e-7)
    np.testing.assert_allclose(
        s.sh[0, 0], [(c / 255 - 0.5) / 0.15 for c in (100, 150, 200)], atol=1e-5
    )
    # SH band 1 (coefficients y, z, x) flips sign for y and z under RUB -> RDF
    expect = np.array([[10, 20, 30], [128, 128, 250], [200, 100, 0]], float)
    expect = (expect - 128) / 128 * np.array([-1, -1, 1])[:, None]
    np.testing.assert_allclose(s.sh[0, 1:], expect, atol=1e-6)
    x, y, z, w = np.asarray(q0) / np.linalg.norm(q0)
    # quantisation: 9-bit magnitudes (v3) or 8-bit components (v2)
    _check_surfel(
        s, 0, (w, x, -y, -z), [1.0, math.exp(-1), math.exp(-2)], tol=1e-5 if version >= 3 else 1e-3
    )
    # extension records (flag 0x2) between header and columns are skipped
    p2 = tmp_path / f"v{version}_ext.spz"
    p2.write_bytes(
        gzip.compress(
            _spz_payload(version, 2, 1, cols, flags=3, ext=b"\x02\x00\xbe\xad" + bytes(12))
        )
    )
    s2 = read_spz(p2)
    np.testing.assert_array_equal(s2.means, s.means)
    np.testing.assert_array_equal(s2.sh, s.sh)


def test_spz_subset_v4_biker(tmp_path, biker_spz):
    rows = np.random.default_rng(5).choice(152_746, 5_000, replace=False)  # any order
    out = tmp_path / "sub.spz"
    write_spz_subset(biker_spz.source, rows, out)
    a, b = _spz_v4_by_hand(BIKER_SPZ), _spz_v4_by_hand(out)
    assert (b["version"], b["n"], b["deg"], b["frac"], b["flags"], b["n_streams"], b["toc"]) == (
        4,
        5_000,
        a["deg"],
        a["frac"],
        a["flags"],
        a["n_streams"],
        a["toc"],
    )
    assert BIKER_SPZ.read_bytes()[12:32] == out.read_bytes()[12:32]
    for ca, cb in zip(a["cols"], b["cols"]):
        w = len(ca) // 152_746
        assert cb == np.frombuffer(ca, np.uint8).reshape(-1, w)[rows].tobytes()
    sub = read_spz(out)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(biker_spz, name)[rows])


def test_spz_subset_gzip(tmp_path):
    cols, _ = _synthetic_spz_cols(3)
    src = tmp_path / "v3.spz"
    src.write_bytes(gzip.compress(_spz_payload(3, 2, 1, cols, flags=1)))
    s = read_spz(src)
    out = tmp_path / "v3_sub.spz"
    write_spz_subset(s.source, np.array([1]), out)
    got = gzip.decompress(out.read_bytes())
    widths = {"positions": 9, "alphas": 1, "colors": 3, "scales": 3, "rotations": 4, "sh": 9}
    want = {k: v[len(v) // 2 :] for k, v in cols.items()}
    assert widths == {k: len(v) for k, v in want.items()}
    assert got == _spz_payload(3, 1, 1, want, flags=1)
    sub = read_spz(out)
    np.testing.assert_array_equal(sub.means, s.means[1:])
    np.testing.assert_array_equal(sub.sh, s.sh[1:])


# ---------------------------------------------------------------- .splat ----


def _splat_record(pos, scale, rgba, rot_bytes) -> bytes:
    return struct.pack("<3f3f4B4B", *pos, *scale, *rgba, *rot_bytes)


def _synthetic_splat(path: Path) -> list[bytes]:
    c45 = round(math.cos(math.pi / 4) * 128 + 128)  # 219: 90 degrees about z
    recs = [
        _splat_record((1, 2, 3), (0.1, 0.2, 0.05), (255, 0, 128, 64), (c45, 128, 128, c45)),
        _splat_record((math.nan, 0, 0), (1, 1, 1), (1, 2, 3, 4), (255, 128, 128, 128)),
        _splat_record((0, 0, 0), (1, 1, 1), (1, 2, 3, 4), (128, 128, 128, 128)),
        _splat_record((-4, 5.5, 0.25), (0.3, 0.01, 0.02), (10, 20, 30, 255), (255, 128, 128, 128)),
    ]
    path.write_bytes(b"".join(recs))
    return recs


def test_splat_synthetic(tmp_path):
    p = tmp_path / "tiny.splat"
    _synthetic_splat(p)
    s = read_splat(p)
    assert s.source.format == "splat" and s.source.num_rows == 4 and s.kind == "3dgs"
    assert s.source.dropped_nonfinite == 2  # a NaN position and a zero quaternion
    np.testing.assert_array_equal(s.source.kept_rows, [0, 3])
    np.testing.assert_allclose(s.means, [[1, 2, 3], [-4, 5.5, 0.25]])
    np.testing.assert_allclose(s.scales, [[0.2, 0.1], [0.3, 0.02]], rtol=1e-6)
    np.testing.assert_allclose(s.scale_n, [0.05, 0.01], rtol=1e-6)  # the dropped axis
    np.testing.assert_allclose(s.opacities, [64 / 255, 1.0], atol=1e-7)
    np.testing.assert_allclose(
        s.sh[0, 0], [(255 / 255 - 0.5) / SH_C0, -0.5 / SH_C0, (128 / 255 - 0.5) / SH_C0], atol=1e-5
    )
    r = s.rotations()[0]  # 90 degrees about z: local y (largest) -> world -x
    assert abs(r[0, 0]) > 0.9999 and abs(r[2, 2]) > 0.9999
    np.testing.assert_allclose(s.rotations()[1], np.eye(3)[:, [0, 2, 1]] * [1, 1, -1], atol=1e-6)


def test_splat_subset(tmp_path):
    p = tmp_path / "tiny.splat"
    recs = _synthetic_splat(p)
    out = tmp_path / "sub.splat"
    write_splat_subset(read_splat(p).source, np.array([3, 0, 3]), out)
    assert out.read_bytes() == recs[3] + recs[0] + recs[3]
    s = read_splat(out)
    assert len(s) == 3 and s.means[1] == pytest.approx([1, 2, 3])


# ------------------------------------------------------------ bad input ----


def test_bad_splat(tmp_path):
    p = tmp_path / "bad.splat"
    p.write_bytes(bytes(33))
    with pytest.raises(DivasInputError, match="multiple of 32"):
        read_splat(p)
    p.write_bytes(b"")
    with pytest.raises(DivasInputError, match="0 bytes"):
        read_splat(p)


def test_bad_spz(tmp_path):
    p = tmp_path / "bad.spz"
    cases = [
        (b"PK\x03\x04" + bytes(40), "not an SPZ"),
        (b"\x1f\x8b" + bytes(30), "corrupt gzip"),
        (gzip.compress(b"ABCD" + bytes(20)), "not an SPZ"),
        (
            gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 1, 1, 0, 12, 0, 0) + bytes(40)),
            "version 1",
        ),
        (gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 3, 0, 0, 12, 0, 0)), "0 points"),
        (
            gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 3, 10, 0, 12, 0, 0) + bytes(50)),
            "truncated",
        ),
        (struct.pack("<4sIIBBBBI", b"NGSP", 5, 1, 0, 12, 0, 5, 32) + bytes(12), "version 5"),
        (struct.pack("<4sIIBBBBI", b"NGSP", 4, 0, 0, 12, 0, 5, 32) + bytes(12), "0 points"),
        (BIKER_SPZ.read_bytes()[:20], "truncated"),
        (BIKER_SPZ.read_bytes()[:1_000_000], "truncated"),
    ]
    corrupt = bytearray(BIKER_SPZ.read_bytes())
    corrupt[112:116] = b"junk"  # the first stream's zstd frame magic (no checksum guards the body)
    cases.append((bytes(corrupt), "corrupt zstd"))
    for data, msg in cases:
        p.write_bytes(data)
        with pytest.raises(DivasInputError, match=msg):
            read_spz(p)


def test_bad_compressed_ply(tmp_path):
    p = tmp_path / "bad.compressed.ply"
    p.write_bytes(BIKER_CPLY.read_bytes()[:1_500_000])
    with pytest.raises(DivasInputError, match="truncated"):
        read_compressed_ply(p)
    vert = np.zeros(
        0,
        dtype=[
            (nm, "<u4")
            for nm in ("packed_position", "packed_rotation", "packed_scale", "packed_color")
        ],
    )
    names = [
        "min_x",
        "min_y",
        "min_z",
        "max_x",
        "max_y",
        "max_z",
        "min_scale_x",
        "min_scale_y",
        "min_scale_z",
        "max_scale_x",
        "max_scale_y",
        "max_scale_z",
    ]
    write_ply_rows(p, {"chunk": np.zeros(0, dtype=[(n, "<f4") for n in names]), "vertex": vert})
    with pytest.raises(DivasInputError, match="0 vertices"):
        read_compressed_ply(p)
    write_ply_rows(
        p,
        {
            "chunk": np.zeros(1, dtype=[(n, "<f4") for n in names]),
            "vertex": np.zeros(600, dtype=vert.dtype),
        },
    )
    with pytest.raises(DivasInputError, match="expected 3"):
        read_compressed_ply(p)


def test_spz_sh_degree_4_is_cut_to_3(tmp_path):
    cols, _ = _synthetic_spz_cols(3)
    sh = np.full((2, 24, 3), 128, np.uint8)
    sh[:, 14, :] = 192  # last degree-3 coefficient (sign +1 under RUB -> RDF)
    sh[:, 15:, :] = 0  # band 4, dropped
    cols["sh"] = sh.tobytes()
    p = tmp_path / "deg4.spz"
    p.write_bytes(gzip.compress(_spz_payload(3, 2, 4, cols)))
    s = read_spz(p)
    assert s.sh_degree == 3 and s.sh.shape == (2, 16, 3)
    np.testing.assert_allclose(s.sh[:, 15], 0.5)
    np.testing.assert_allclose(s.sh[:, 1:15], 0.0)

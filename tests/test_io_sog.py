"""SOG reader and subset writer, checked against PlayCanvas's published SOG definition.

Real data (read-only, ``tests/data/README.md``), from playcanvas/engine @ 0aaef5e :
``examples/assets/splats/``:

* ``playcanvas-sog/playbot_lod3/`` — SOG version 2, 31,000 Gaussians, 2 SH bands
  as a palette (CC-BY-4.0, ``playbot.txt``);
* ``playcanvas-sog/playcanvas-logo/`` — the original layout (no ``version``),
  307,128 Gaussians, no SH bands (MIT).

The reference decoder here (:func:`_row_by_hand`) works per row from the texel
bytes OpenCV gives and ``meta.json``, with ``math``, following the format text
(positions: 16-bit ``means_l + 256 * means_u``, lerp in mins/maxs, inverse of
``sign(x) * ln(|x| + 1)``; quaternions: smallest three, tag ``252 + index of the
largest``; codebooks / 8-bit ranges; the SH palette 64 entries per row). It shares
no code with ``divas_engine.io.sog*``. Synthetic SOGs of both layouts are built
here from random bytes.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from divas_engine.cli import main
from divas_engine.errors import DivasInputError
from divas_engine.export import export_selection
from divas_engine.io import sog_subset
from divas_engine.io.load import detect_format, load_scene
from tests.test_io_formats import _check_surfel

SOG = Path(__file__).resolve().parent / "data" / "playcanvas-sog"
PLAYBOT, LOGO = SOG / "playbot_lod3", SOG / "playcanvas-logo"
COEFFS = {1: 3, 2: 8, 3: 15}


# ----------------------------------------------------- reference decoder ----


def _rgba(data: bytes) -> np.ndarray:
    im = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    alpha = im[..., 3] if im.shape[2] == 4 else np.full(im.shape[:2], 255, np.uint8)
    return np.stack([im[..., 2], im[..., 1], im[..., 0], alpha], axis=-1)


def _hand_open(path: Path) -> tuple[dict, dict]:
    """meta.json and every image as ``[H,W,4]`` RGBA, from a folder or a ``.sog`` ZIP."""
    if path.suffix == ".sog":
        with zipfile.ZipFile(path) as zf:
            read = {n: zf.read(n) for n in zf.namelist()}.__getitem__
            meta = json.loads(read("meta.json"))
    else:
        meta = json.loads((path / "meta.json").read_bytes())
        read = lambda n: (path / n).read_bytes()  # noqa: E731
    roles = {"means": ("means_l", "means_u"), "quats": ("quats",), "scales": ("scales",)}
    roles |= {"sh0": ("sh0",), "shN": ("shN_centroids", "shN_labels")}
    tex = {
        role: _rgba(read(name))
        for key, names in roles.items()
        if key in meta
        for role, name in zip(names, meta[key]["files"])
    }
    return meta, tex


def _lerp(lo, hi, b, full=255):
    return lo + (hi - lo) * b / full


def _row_by_hand(meta: dict, tex: dict, i: int) -> dict:
    w = tex["means_l"].shape[1]
    x, y = i % w, i // w

    def px(role):
        return [int(v) for v in tex[role][y, x]]

    lo, hi = px("means_l"), px("means_u")
    mins, maxs = meta["means"]["mins"], meta["means"]["maxs"]
    pos = []
    for a in range(3):
        n = _lerp(mins[a], maxs[a], lo[a] + 256 * hi[a], 65535)
        pos.append(math.copysign(math.exp(abs(n)) - 1, n))
    *small, tag = px("quats")
    largest = tag - 252
    assert 0 <= largest <= 3
    q = [0.0] * 4  # w, x, y, z
    for j, b in zip([j for j in range(4) if j != largest], small):
        q[j] = (b / 255 * 2 - 1) / math.sqrt(2)
    q[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in q)))
    s, c = px("scales"), px("sh0")
    if meta.get("version") == 2:
        log_s = [meta["scales"]["codebook"][s[a]] for a in range(3)]
        dc = [meta["sh0"]["codebook"][c[k]] for k in range(3)]
        alpha = c[3] / 255
    else:
        sm, sx, cm, cx = (meta[k][m] for k in ("scales", "sh0") for m in ("mins", "maxs"))
        log_s = [_lerp(sm[a], sx[a], s[a]) for a in range(3)]
        dc = [_lerp(cm[k], cx[k], c[k]) for k in range(3)]
        alpha = 1 / (1 + math.exp(-_lerp(cm[3], cx[3], c[3])))
    rest = None
    if "shN" in meta:
        cen = tex["shN_centroids"]
        coeffs = cen.shape[1] // 64
        lab = px("shN_labels")
        label = lab[0] + 256 * lab[1]
        shn = meta["shN"]
        rest = []
        for j in range(coeffs):
            b = [int(v) for v in cen[label // 64, (label % 64) * coeffs + j, :3]]
            if meta.get("version") == 2:
                rest.append([shn["codebook"][v] for v in b])
            else:
                rest.append([_lerp(shn["mins"], shn["maxs"], v) for v in b])
    return {"pos": pos, "quat": q, "scales": [math.exp(v) for v in log_s], "dc": dc,
            "alpha": alpha, "rest": rest}  # fmt: skip


def _check_rows(scene, meta, tex, rows):
    for i in rows:
        h = _row_by_hand(meta, tex, int(i))
        np.testing.assert_allclose(scene.means[i], h["pos"], rtol=1e-6, atol=1e-6)
        assert scene.opacities[i] == pytest.approx(h["alpha"], abs=1e-6)
        np.testing.assert_allclose(scene.sh[i, 0], h["dc"], rtol=1e-6, atol=1e-6)
        _check_surfel(scene, i, h["quat"], h["scales"])
        if h["rest"] is not None:
            np.testing.assert_allclose(scene.sh[i, 1:], h["rest"], rtol=1e-6, atol=1e-6)


# -------------------------------------------------------- the real files ----


@pytest.fixture(scope="module")
def playbot():
    return load_scene(PLAYBOT / "meta.json")


@pytest.fixture(scope="module")
def logo():
    return load_scene(LOGO)


def test_counts_and_detection(playbot, logo):
    assert len(playbot) == 31_000 and playbot.sh_degree == 2 and playbot.kind == "3dgs"
    assert len(logo) == 307_128 and logo.sh_degree == 0 and logo.kind == "3dgs"
    for s, version in ((playbot, 2), (logo, 1)):
        assert s.source.format == "sog" and s.source.dropped_nonfinite == 0
        assert s.source.path.name == "meta.json" and s.extras["sog_version"] == version
        assert s.extras["sog_bundled"] is False
    for p in (PLAYBOT, PLAYBOT / "meta.json", LOGO):
        assert detect_format(p) == "sog"


@pytest.mark.parametrize("path,count", [(PLAYBOT / "meta.json", 31_000), (LOGO, 307_128)])
def test_divas_info_reports_the_count(path, count, capsys):
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["count"] == count and info["format"] == "sog"


def _inv_log(v):
    v = np.asarray(v, np.float64)
    return np.sign(v) * np.expm1(np.abs(v))


@pytest.mark.parametrize("name", ["playbot", "logo"])
def test_bounds_match_meta(name, request):
    scene = request.getfixturevalue(name)
    meta = json.loads((PLAYBOT if name == "playbot" else LOGO).joinpath("meta.json").read_text())
    lo_n, hi_n = np.array(meta["means"]["mins"]), np.array(meta["means"]["maxs"])
    assert (scene.means.min(0) >= _inv_log(lo_n) - 1e-6).all()
    assert (scene.means.max(0) <= _inv_log(hi_n) + 1e-6).all()
    # splat-transform maps each axis's extreme points to 0 and 65535; the logo's older
    # encoder comes within one 16-bit step of them
    step = 0 if name == "playbot" else 1.01 * (hi_n - lo_n) / 65535
    assert (scene.means.min(0) <= _inv_log(lo_n + step) + 1e-6).all()
    assert (scene.means.max(0) >= _inv_log(hi_n - step) - 1e-6).all()
    allscales = np.concatenate([scene.scales.ravel(), scene.scale_n])
    if name == "playbot":
        cb = np.array(meta["scales"]["codebook"])
        lo, hi = np.exp(cb.min()), np.exp(cb.max())
        dc = np.array(meta["sh0"]["codebook"])
        op_lo, op_hi = 0.0, 1.0
        dc_lo, dc_hi = [dc.min()] * 3, [dc.max()] * 3
    else:
        lo, hi = np.exp(min(meta["scales"]["mins"])), np.exp(max(meta["scales"]["maxs"]))
        m, x = meta["sh0"]["mins"], meta["sh0"]["maxs"]
        op_lo, op_hi = 1 / (1 + math.exp(-m[3])), 1 / (1 + math.exp(-x[3]))
        dc_lo, dc_hi = m[:3], x[:3]
    assert lo * (1 - 1e-6) <= allscales.min() and allscales.max() <= hi * (1 + 1e-6)
    assert op_lo - 1e-6 <= scene.opacities.min() and scene.opacities.max() <= op_hi + 1e-6
    assert (scene.sh[:, 0].min(0) >= np.array(dc_lo) - 1e-6).all()
    assert (scene.sh[:, 0].max(0) <= np.array(dc_hi) + 1e-6).all()


def test_playbot_rows_by_hand(playbot):
    meta, tex = _hand_open(PLAYBOT)
    w = tex["means_l"].shape[1]
    assert tex["means_l"].shape[:2] == (176, 180) and tex["shN_centroids"].shape[:2] == (256, 512)
    _check_rows(playbot, meta, tex, [0, 1, w - 1, w, 12_345, 30_999])


def test_logo_rows_by_hand(logo):
    meta, tex = _hand_open(LOGO)
    assert "version" not in meta and tex["means_l"].shape[:2] == (560, 560)
    _check_rows(logo, meta, tex, [0, 559, 560, 100_000, 307_127])


def test_playbot_sh_palette(playbot):
    """Every label names an entry of the 16,384-entry palette; a sample of rows by hand."""
    meta, tex = _hand_open(PLAYBOT)
    lab = tex["shN_labels"].reshape(-1, 4)[:31_000].astype(int)
    labels = lab[:, 0] + 256 * lab[:, 1]
    assert meta["shN"]["bands"] == 2 and labels.max() < meta["shN"]["count"] == 16_384
    rows = np.random.default_rng(3).choice(31_000, 40, replace=False)
    for i in rows:
        rest = _row_by_hand(meta, tex, int(i))["rest"]
        np.testing.assert_allclose(playbot.sh[i, 1:], rest, rtol=1e-6, atol=1e-6)
    # two Gaussians with one label share their SH bands exactly
    same = np.flatnonzero(labels == labels[rows[0]])
    assert np.array_equal(playbot.sh[same[0], 1:], playbot.sh[same[-1], 1:])


@pytest.mark.parametrize("name,folder", [("playbot", PLAYBOT), ("logo", LOGO)])
def test_real_subset_export(name, folder, request, tmp_path):
    scene = request.getfixturevalue(name)
    sel = scene.means[:, 0] > 0.25
    for out in (tmp_path / "sub.sog", tmp_path / "sub"):
        res = export_selection(scene, sel, out)
        back = load_scene(res.path)
        assert res.format == "sog" and len(back) == res.count == int(sel.sum())
        assert back.extras["sog_bundled"] == (out.suffix == ".sog")
        for a in ("means", "quats", "scales", "scale_n", "opacities", "sh"):
            assert np.array_equal(getattr(back, a), getattr(scene, a)[sel]), a
    meta, tex = _hand_open(tmp_path / "sub")
    src = json.loads((folder / "meta.json").read_text())
    n = int(sel.sum())
    w = math.ceil(math.sqrt(n) / 4) * 4
    assert tex["means_l"].shape[:2] == (math.ceil(n / w / 4) * 4, w)
    assert meta["means"]["mins"] == src["means"]["mins"]
    if name == "playbot":
        lab = tex["shN_labels"].reshape(-1, 4)[:n].astype(int)
        used = np.unique(lab[:, 0] + 256 * lab[:, 1])
        assert meta["count"] == n and meta["shN"]["count"] == len(used) == used.max() + 1
        assert meta["scales"]["codebook"] == src["scales"]["codebook"]
    else:
        assert all(meta[k]["shape"][0] == n for k in ("means", "scales", "quats", "sh0"))


# ------------------------------------------------------- synthetic SOGs ----


def _webp(rgba: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".webp", rgba[..., [2, 1, 0, 3]], [cv2.IMWRITE_WEBP_QUALITY, 101])
    assert ok
    return buf.tobytes()


def _synthetic(n=300, version=2, bands=1, palette=70, width=13, seed=0) -> dict[str, bytes]:
    """meta.json and images of a random SOG: quantised bytes, codebooks / ranges."""
    rng = np.random.default_rng(seed)
    h = math.ceil(n / width) + 1  # a spare row: trailing texels are ignored

    def img(alpha=None, lo=0, hi=256):
        a = rng.integers(lo, hi, (h, width, 4), dtype=np.uint8)
        a[..., 3] = 255 if alpha is None else alpha
        return a

    quats = img(rng.integers(252, 256, (h, width)), 37, 219)  # |stored three| <= 0.5
    files = {"means_l": img(), "means_u": img(), "quats": quats, "scales": img()}
    files["sh0"] = img(rng.integers(1, 256, (h, width)))
    if bands:
        lab = rng.integers(0, palette, (h, width))
        files["shN_labels"] = img()
        files["shN_labels"][..., 0], files["shN_labels"][..., 1] = lab & 255, lab >> 8
        cen = rng.integers(0, 256, (math.ceil(palette / 64), 64 * COEFFS[bands], 4), np.uint8)
        files["shN_centroids"] = cen
        files["shN_centroids"][..., 3] = 255
    means = {"mins": [-1.2, -0.9, -1.5], "maxs": [1.1, 0.8, 0.3]}
    names = {k: [f"{k}_l.webp", f"{k}_u.webp"] if k == "means" else [f"{k}.webp"] for k in
             ("means", "quats", "scales", "sh0")}  # fmt: skip
    if version == 2:
        cb = lambda lo, hi: sorted(rng.uniform(lo, hi, 256).tolist())  # noqa: E731
        meta = {"version": 2, "count": n, "means": {**means, "files": names["means"]},
                "scales": {"codebook": cb(-7, -2), "files": names["scales"]},
                "quats": {"files": names["quats"]},
                "sh0": {"codebook": cb(-2, 2), "files": names["sh0"]}}  # fmt: skip
        if bands:
            meta["shN"] = {"count": palette, "bands": bands, "codebook": cb(-1, 1),
                           "files": ["shN_centroids.webp", "shN_labels.webp"]}  # fmt: skip
    else:
        meta = {"means": {"shape": [n, 3], "dtype": "float32", **means, "files": names["means"]},
                "scales": {"shape": [n, 3], "mins": [-7, -6, -8], "maxs": [-2, -1, -3],
                           "files": names["scales"]},
                "quats": {"shape": [n, 4], "encoding": "quaternion_packed",
                          "files": names["quats"]},
                "sh0": {"shape": [n, 1, 4], "mins": [-2, -1.5, -1, -4], "maxs": [2, 1, 3, 5],
                        "files": names["sh0"]}}  # fmt: skip
        if bands:
            meta["shN"] = {"shape": [n, 3 * COEFFS[bands]], "mins": -0.7, "maxs": 0.9,
                           "quantization": 8,
                           "files": ["shN_centroids.webp", "shN_labels.webp"]}  # fmt: skip
    out = {"meta.json": json.dumps(meta).encode()}
    out |= {f"{k}.webp": _webp(v) for k, v in files.items()}
    return out


def _save(files: dict[str, bytes], path: Path) -> Path:
    if path.suffix == ".sog":
        with zipfile.ZipFile(path, "w") as zf:
            for name, data in files.items():
                zf.writestr(name, data)
    else:
        path.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            (path / name).write_bytes(data)
    return path


@pytest.mark.parametrize("version,bands", [(2, 1), (2, 3), (None, 2), (None, 0)])
@pytest.mark.parametrize("bundled", [False, True])
def test_synthetic_round_trip_and_subset(tmp_path, version, bands, bundled):
    n = 300
    src = _save(_synthetic(n, version, bands), tmp_path / ("in.sog" if bundled else "in"))
    scene = load_scene(src)
    assert len(scene) == n and scene.sh_degree == bands and scene.extras["sog_bundled"] == bundled
    meta, tex = _hand_open(src)
    _check_rows(scene, meta, tex, range(n))
    sel = np.random.default_rng(1).random(n) < 0.3
    res = export_selection(scene, sel, tmp_path / ("out.sog" if bundled else "out"))
    assert res.path == (tmp_path / "out.sog" if bundled else tmp_path / "out" / "meta.json")
    back = load_scene(res.path)
    assert back.extras["sog_bundled"] == bundled and back.extras["sog_version"] == (version or 1)
    for a in ("means", "quats", "scales", "scale_n", "opacities", "sh"):
        assert np.array_equal(getattr(back, a), getattr(scene, a)[sel]), a
    # the written files decode, by hand too, to the kept rows
    meta2, tex2 = _hand_open(tmp_path / ("out.sog" if bundled else "out"))
    kept = np.flatnonzero(sel)
    for j in (0, len(kept) // 2, len(kept) - 1):
        assert _row_by_hand(meta2, tex2, j) == _row_by_hand(meta, tex, int(kept[j]))


def test_png_textures_and_rgb_under_zero_alpha(tmp_path):
    """PNG textures read (the format allows any 8-bit RGBA image); a Gaussian whose opacity
    byte is 0 loses only its colour in a WebP export (sog_subset docstring)."""
    files = _synthetic(100, 2, 0)
    meta = json.loads(files["meta.json"])
    sh0 = _rgba(files["sh0.webp"])
    sh0[0, 5] = (200, 100, 50, 0)  # row 5: opacity byte 0, a colour
    ok, png = cv2.imencode(".png", sh0[..., [2, 1, 0, 3]])
    files["sh0.png"] = png.tobytes()
    meta["sh0"]["files"] = ["sh0.png"]
    files["meta.json"] = json.dumps(meta).encode()
    scene = load_scene(_save(files, tmp_path / "in"))
    cb = meta["sh0"]["codebook"]
    np.testing.assert_allclose(scene.sh[5, 0], [cb[200], cb[100], cb[50]], rtol=1e-6)
    assert scene.opacities[5] == 0
    sel = np.ones(100, bool)
    back = load_scene(export_selection(scene, sel, tmp_path / "out").path)
    others = np.arange(100) != 5
    assert np.array_equal(back.sh[others], scene.sh[others])
    assert np.array_equal(back.means, scene.means) and back.opacities[5] == 0


def test_invalid_quaternion_tag_drops_the_row(tmp_path):
    files = _synthetic(50, 2, 0)
    q = _rgba(files["quats.webp"])
    q[0, 7, 3] = 17
    files["quats.webp"] = _webp(q)
    scene = load_scene(_save(files, tmp_path / "in"))
    assert len(scene) == 49 and scene.source.num_rows == 50 and 7 not in scene.source.kept_rows


# ------------------------------------------------------------ bad input ----


def _edit(files, **meta_changes):
    meta = json.loads(files["meta.json"])
    for path, value in meta_changes.items():
        *keys, last = path.split("__")
        node = meta
        for k in keys:
            node = node[k]
        if value is None:
            node.pop(last)
        else:
            node[last] = value
    return {**files, "meta.json": json.dumps(meta).encode()}


def _bad_cases():
    base = _synthetic(60, 2, 1, seed=5)
    v1 = _synthetic(60, None, 0, seed=6)
    small = np.zeros((3, 7, 4), np.uint8)
    small[..., 3] = 255
    lossy = cv2.imencode(".webp", small[..., :3], [cv2.IMWRITE_WEBP_QUALITY, 80])[1].tobytes()
    lab = _rgba(base["shN_labels.webp"])
    lab[0, 0, :2] = (200, 0)  # label 200 of a 70-entry palette
    return {
        "missing file": ({k: v for k, v in base.items() if k != "scales.webp"}, "missing"),
        "wrong size": ({**base, "sh0.webp": _webp(small)}, "but means_l is"),
        "count too big": (_edit(base, count=10_000), "cannot hold"),
        "huge image": (
            {**base, "means_l.webp": _webp(np.full((300, 300, 4), 255, np.uint8))},
            "far more than",
        ),  # fmt: skip
        "not json": ({**base, "meta.json": b"{nope"}, "not JSON"),
        "no means": (_edit(base, means=None), "'means' missing"),
        "nan bound": (
            {**base, "meta.json": base["meta.json"].replace(b'"mins": [-1.2,', b'"mins": [NaN,')},
            "NaN",
        ),
        "long codebook": (_edit(base, sh0__codebook=[0.0] * 300), "300 > 256"),
        "short codebook": (_edit(base, sh0__codebook=[0.0] * 10), "past its 10-entry"),
        "version 3": (_edit(base, version=3), "unsupported SOG version 3"),
        "zero count": (_edit(base, count=0), "empty scene"),
        "escaping name": (_edit(base, scales__files=["../scales.webp"]), "leaves the scene"),
        "garbage image": ({**base, "means_l.webp": b"RIFF0000WEBPjunk" * 4}, "unknown WebP"),
        "not an image": ({**base, "means_l.webp": b"hello"}, "not a WebP"),
        "lossy webp": ({**base, "sh0.webp": lossy}, "lossy WebP"),
        "label past palette": ({**base, "shN_labels.webp": _webp(lab)}, "past the 70-entry"),
        "bad bands": (_edit(base, shN__bands=5), "shN.bands"),
        "v1 shape mismatch": (_edit(v1, sh0__shape=[59, 1, 4]), "sh0.shape[0] = 59"),
        "v1 no shape": (_edit(v1, means__shape=None), "means.shape"),
    }


@pytest.mark.parametrize("case", list(_bad_cases()))
@pytest.mark.parametrize("bundled", [False, True])
def test_bad_input(tmp_path, case, bundled):
    files, msg = _bad_cases()[case]
    path = _save(files, tmp_path / ("bad.sog" if bundled else "bad"))
    with pytest.raises(DivasInputError, match=re.escape(msg)) as e:
        load_scene(path)
    assert str(path) in str(e.value)  # names the file (or the bundle member)


def test_bad_containers(tmp_path):
    junk = tmp_path / "junk.sog"
    junk.write_bytes(b"PK\x03\x04 definitely not a zip")
    with pytest.raises(DivasInputError, match="not a readable .sog"):
        load_scene(junk)
    good = _save(_synthetic(40, 2, 0), tmp_path / "good.sog")
    cut = tmp_path / "cut.sog"
    cut.write_bytes(good.read_bytes()[:-200])
    with pytest.raises(DivasInputError, match="cut.sog"):
        load_scene(cut)
    nometa = tmp_path / "nometa.sog"
    with zipfile.ZipFile(nometa, "w") as zf:
        zf.writestr("readme.txt", "x")
    with pytest.raises(DivasInputError, match="no meta.json"):
        load_scene(nometa)
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(DivasInputError, match="directory"):
        load_scene(tmp_path / "empty_dir")
    npz = tmp_path / "grid.npz"
    np.savez(npz, density=np.zeros((2, 2, 2)))
    assert detect_format(npz) == "npz"


# ------------------------------------------------------ export safety ----


def test_export_refuses_the_input_and_foreign_folders(tmp_path):
    src = _save(_synthetic(40, 2, 0), tmp_path / "in")
    scene = load_scene(src)
    sel = np.ones(40, bool)
    for out in (src, src / "meta.json"):
        with pytest.raises(DivasInputError, match="refusing to overwrite the input"):
            export_selection(scene, sel, out)
    bundle = _save(_synthetic(40, 2, 0), tmp_path / "in.sog")
    with pytest.raises(DivasInputError, match="refusing to overwrite the input"):
        export_selection(load_scene(bundle), sel, bundle)
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "notes.txt").write_text("mine")
    with pytest.raises(DivasInputError, match="refusing to replace"):
        export_selection(scene, sel, docs)
    assert (docs / "notes.txt").read_text() == "mine"


def _snapshot(path: Path):
    return {p.name: p.read_bytes() for p in path.iterdir()} if path.is_dir() else path.read_bytes()


@pytest.mark.parametrize("name", ["out", "out.sog"])
def test_failed_export_leaves_previous_output(tmp_path, monkeypatch, name):
    scene = load_scene(_save(_synthetic(40, 2, 1), tmp_path / "in"))
    sel = np.arange(40) < 10
    first = export_selection(scene, sel, tmp_path / name).path
    before = _snapshot(tmp_path / name)
    if name.endswith(".sog"):  # the temp file is written, then the disk fails

        def broken(fd):
            raise OSError("disk full")

        monkeypatch.setattr(sog_subset.os, "fsync", broken)
    else:  # the temp folder gets one file, then the disk fails
        real = Path.write_bytes
        calls = []

        def broken(self, data):
            calls.append(self)
            if len(calls) > 1:
                raise OSError("disk full")
            return real(self, data)

        monkeypatch.setattr(Path, "write_bytes", broken)
    # a disk error is one DivasInputError naming the output, not a bare OSError
    with pytest.raises(DivasInputError, match="disk full"):
        export_selection(scene, ~sel, tmp_path / name)
    monkeypatch.undo()
    assert _snapshot(tmp_path / name) == before and len(load_scene(first)) == 10
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["in", name])  # no temp left


def test_export_replaces_a_previous_sog_folder(tmp_path):
    scene = load_scene(_save(_synthetic(40, None, 2), tmp_path / "in"))
    sel = np.arange(40) < 30
    export_selection(scene, sel, tmp_path / "out")
    (tmp_path / "out" / "stale.webp").write_bytes(b"old")
    res = export_selection(scene, ~sel, tmp_path / "out" / "meta.json")
    assert len(load_scene(res.path)) == 10 and not (tmp_path / "out" / "stale.webp").exists()
    shutil.rmtree(tmp_path / "in")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_encoder_check_catches_a_lossy_round_trip(monkeypatch):
    img = np.full((4, 4, 4), 255, np.uint8)
    img[0, 0, 0] = 7
    monkeypatch.setattr(sog_subset.cv2, "imdecode", lambda *a: np.full((4, 4, 4), 255, np.uint8))
    with pytest.raises(RuntimeError, match="losslessly"):
        sog_subset.encode_webp_lossless(img, "x.webp")


def test_session_names_sog_exports_in_the_input_layout(tmp_path):
    from divas_engine.session.backends.surfels import export_suffix as suffix

    files = _synthetic(20, 2, 0)
    assert suffix(load_scene(_save(files, tmp_path / "a.sog"))) == ".sog"
    assert suffix(load_scene(_save(files, tmp_path / "a"))) == ""  # a folder

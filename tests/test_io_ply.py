"""Standard 2DGS/3DGS PLY loading, exact subset export, density grids and bad input.

Real files: ``tests/data/gaussiansplats3d-lod/*.ply`` from mkkellogg/GaussianSplats3D
(pull request 477 @ e154f37, MIT), standard binary 3DGS PLYs with SH degree 3.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import plyfile
import pytest

from divas_engine import DivasInputError, load_scene
from divas_engine.export import export_selection, file_labels
from divas_engine.geometry import quat_to_rotmat, rotmat_to_quat
from divas_engine.io.density_grid import read_density_grid
from divas_engine.io.ply import write_ply_rows, write_surfel_ply
from divas_engine.scene import DensityGrid, SurfelScene

from .conftest import REPO

LOD_FILES = {"lod1_tile_0_0.5x.ply": 14051, "lod2_tile_0.ply": 6831, "lod3_tile_0.ply": 1971}


def _gaussian_rows(n: int, sh_degree: int, n_scales: int, rng: np.random.Generator) -> np.ndarray:
    k = (sh_degree + 1) ** 2
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity"] + [f"scale_{i}" for i in range(n_scales)] + [f"rot_{i}" for i in range(4)]
    rows = np.zeros(n, dtype=[(f, "<f4") for f in names])
    for f in names:
        rows[f] = rng.normal(size=n).astype(np.float32)
    for i in range(n_scales):
        rows[f"scale_{i}"] = rng.uniform(-5, 0, n)
    return rows


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    r = quat_to_rotmat(q)
    assert np.allclose(r @ np.swapaxes(r, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    assert np.allclose(rotmat_to_quat(r), q, atol=1e-9)
    # hand case: 90° about z maps x to y
    rz = quat_to_rotmat(np.array([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]]))[0]
    assert np.allclose(rz @ [1, 0, 0], [0, 1, 0])


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
def test_2dgs_ply_activations_and_sh_layout(tmp_path, sh_degree):
    rng = np.random.default_rng(sh_degree)
    rows = _gaussian_rows(300, sh_degree, 2, rng)
    write_ply_rows(tmp_path / "s.ply", {"vertex": rows})
    s = load_scene(tmp_path / "s.ply")
    assert isinstance(s, SurfelScene) and s.kind == "2dgs" and s.sh_degree == sh_degree
    assert s.means.dtype == np.float32 and s.sh.dtype == np.float32
    assert np.allclose(s.means[:, 1], rows["y"])
    assert np.allclose(s.scales[:, 0], np.exp(rows["scale_0"].astype(np.float64)), rtol=1e-6)
    assert np.allclose(
        s.opacities, 1 / (1 + np.exp(-rows["opacity"].astype(np.float64))), atol=1e-6
    )
    q = np.stack([rows[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    assert np.allclose(s.quats, q / np.linalg.norm(q, axis=1, keepdims=True), atol=1e-6)
    k = (sh_degree + 1) ** 2
    assert np.array_equal(s.sh[:, 0, 2], rows["f_dc_2"])
    if k > 1:  # channel-major f_rest: coefficient j+1 of channel c is f_rest_{c*(k-1)+j}
        assert np.array_equal(s.sh[:, 1, 0], rows["f_rest_0"])
        assert np.array_equal(s.sh[:, k - 1, 1], rows[f"f_rest_{2 * (k - 1) - 1}"])
        assert np.array_equal(s.sh[:, 2, 2], rows[f"f_rest_{2 * (k - 1) + 1}"])


def test_3dgs_flattened_to_two_largest_axes(tmp_path):
    rows = _gaussian_rows(3, 0, 3, np.random.default_rng(1))
    # Gaussian 0: identity rotation, scales (z, x, y) order of size: z largest, x smallest
    rows[0]["rot_0"], rows[0]["rot_1"], rows[0]["rot_2"], rows[0]["rot_3"] = 1, 0, 0, 0
    rows[0]["scale_0"], rows[0]["scale_1"], rows[0]["scale_2"] = (
        np.log(0.01),
        np.log(0.2),
        np.log(0.5),
    )
    # Gaussian 1: 90° about z (x→y, y→−x), largest local x, then local y
    c = np.cos(np.pi / 4)
    rows[1]["rot_0"], rows[1]["rot_1"], rows[1]["rot_2"], rows[1]["rot_3"] = (
        2 * c,
        0,
        0,
        2 * c,
    )  # unnormalised
    rows[1]["scale_0"], rows[1]["scale_1"], rows[1]["scale_2"] = (
        np.log(0.3),
        np.log(0.1),
        np.log(0.001),
    )
    write_ply_rows(tmp_path / "g.ply", {"vertex": rows})
    s = load_scene(tmp_path / "g.ply")
    assert s.kind == "3dgs"
    r = quat_to_rotmat(s.quats.astype(np.float64))
    assert np.allclose(s.scales[0], [0.5, 0.2], rtol=1e-6)
    assert np.allclose(r[0][:, 0], [0, 0, 1], atol=1e-6) and np.allclose(
        r[0][:, 1], [0, 1, 0], atol=1e-6
    )
    assert np.allclose(abs(r[0][:, 2] @ [1, 0, 0]), 1, atol=1e-6)  # normal = dropped axis
    assert np.allclose(s.scales[1], [0.3, 0.1], rtol=1e-6)
    assert np.allclose(r[1][:, 0], [0, 1, 0], atol=1e-6) and np.allclose(
        r[1][:, 1], [-1, 0, 0], atol=1e-6
    )
    assert np.allclose(np.linalg.det(r), 1, atol=1e-5)


@pytest.mark.parametrize("name,count", sorted(LOD_FILES.items()))
def test_real_3dgs_ply_matches_plyfile(real_data, name, count):
    path = real_data / "gaussiansplats3d-lod" / name
    s = load_scene(path)
    raw = plyfile.PlyData.read(str(path))["vertex"].data
    assert len(raw) == count and s.source.num_rows == count
    assert s.kind == "3dgs" and s.sh_degree == 3 and s.sh.shape == (len(s), 16, 3)
    keep = s.source.kept_rows
    assert np.array_equal(s.means[:, 0], raw["x"][keep])
    assert np.array_equal(s.sh[:, 5, 1], raw["f_rest_19"][keep])  # G channel, coefficient 5
    smax = np.exp(np.stack([raw[f"scale_{i}"] for i in range(3)], 1).astype(np.float64)).max(1)[
        keep
    ]
    assert np.allclose(s.scales[:, 0], smax, rtol=1e-5)
    # the dropped normal-axis scale s_3 is kept: the Gaussian stays whole
    smin = np.exp(np.stack([raw[f"scale_{i}"] for i in range(3)], 1).astype(np.float64)).min(1)
    assert s.scale_n is not None and np.allclose(s.scale_n, smin[keep], rtol=1e-5)
    assert s.source.dropped_nonfinite == count - len(s)


def test_nan_rows_dropped_and_counted(tmp_path):
    rows = _gaussian_rows(50, 1, 2, np.random.default_rng(2))
    rows["x"][3] = np.nan
    rows["f_rest_4"][10] = np.inf
    rows["scale_1"][20] = -np.inf  # exp(-inf) = 0 is finite in stored space but -inf is not
    write_ply_rows(tmp_path / "n.ply", {"vertex": rows})
    s = load_scene(tmp_path / "n.ply")
    assert len(s) == 47 and s.source.dropped_nonfinite == 3
    assert not np.isin([3, 10, 20], s.source.kept_rows).any()
    assert np.array_equal(s.means[:, 1], np.delete(rows["y"], [3, 10, 20]))


def test_ascii_and_big_endian_ply_load_identically(tmp_path):
    rows = _gaussian_rows(40, 1, 2, np.random.default_rng(3))
    write_ply_rows(tmp_path / "b.ply", {"vertex": rows})
    el = plyfile.PlyElement.describe(rows, "vertex")
    plyfile.PlyData([el], text=True).write(str(tmp_path / "a.ply"))
    plyfile.PlyData([el], byte_order=">").write(str(tmp_path / "be.ply"))
    b, a, be = (load_scene(tmp_path / n) for n in ("b.ply", "a.ply", "be.ply"))
    assert np.allclose(a.means, b.means, atol=1e-6) and np.allclose(a.sh, b.sh, atol=1e-6)
    assert np.array_equal(be.means, b.means) and np.array_equal(be.quats, b.quats)


def test_surfel_ply_writer_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    n = 100
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    s = SurfelScene(
        rng.normal(size=(n, 3)).astype(np.float32),
        q,
        rng.uniform(0.01, 0.1, (n, 2)).astype(np.float32),
        rng.uniform(0.05, 0.95, n).astype(np.float32),
        rng.normal(size=(n, 4, 3)).astype(np.float32),
        1,
    )
    write_surfel_ply(tmp_path / "w.ply", s)
    r = load_scene(tmp_path / "w.ply")
    assert r.kind == "2dgs" and r.sh_degree == 1
    assert np.array_equal(r.means, s.means) and np.array_equal(r.sh, s.sh)
    assert np.allclose(r.scales, s.scales, rtol=1e-6) and np.allclose(
        r.opacities, s.opacities, atol=1e-6
    )
    assert np.allclose(np.abs((r.quats * s.quats).sum(1)), 1, atol=1e-6)


def _write_bytes(path, data: bytes):
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    "case,needle",
    [
        ("truncated", "truncated"),
        ("missing", "missing required"),
        ("not_ply", "not a PLY"),
        ("empty", "empty scene"),
        ("all_nan", "NaN/Inf"),
        ("bad_sh", "SH degree"),
        ("bad_header", "malformed PLY header"),
        ("unknown_ext", "unknown scene format"),
        ("missing_file", "does not exist"),
    ],
)
def test_bad_ply_input_names_file_and_problem(tmp_path, case, needle):
    rng = np.random.default_rng(5)
    p = tmp_path / f"{case}.ply"
    if case == "truncated":
        write_ply_rows(p, {"vertex": _gaussian_rows(100, 0, 2, rng)})
        p.write_bytes(p.read_bytes()[:-7])
    elif case == "missing":
        rows = _gaussian_rows(10, 0, 2, rng)
        write_ply_rows(p, {"vertex": rows[[n for n in rows.dtype.names if n != "opacity"]]})
    elif case == "not_ply":
        _write_bytes(p, b"hello world, I am not a PLY\n")
    elif case == "empty":
        write_ply_rows(p, {"vertex": _gaussian_rows(0, 0, 2, rng)})
    elif case == "all_nan":
        rows = _gaussian_rows(4, 0, 2, rng)
        rows["z"] = np.nan
        write_ply_rows(p, {"vertex": rows})
    elif case == "bad_sh":
        rows = _gaussian_rows(4, 1, 2, rng)
        write_ply_rows(p, {"vertex": rows[[n for n in rows.dtype.names if n != "f_rest_8"]]})
    elif case == "bad_header":
        _write_bytes(p, b"ply\nformat binary_little_endian 1.0\nelement vertex abc\nend_header\n")
    elif case == "unknown_ext":
        p = _write_bytes(tmp_path / "scene.xyz", b"1 2 3\n")
    elif case == "missing_file":
        p = tmp_path / "nope.ply"
    with pytest.raises(DivasInputError) as ei:
        load_scene(p)
    assert str(p) in str(ei.value) and needle in str(ei.value)


def test_export_is_exact_subset_of_original_ply(tmp_path, real_data):
    src = real_data / "gaussiansplats3d-lod" / "lod3_tile_0.ply"
    s = load_scene(src)
    sel = np.zeros(len(s), bool)
    sel[::3] = True
    res = export_selection(s, sel, tmp_path / "sub.ply", labels_path=tmp_path / "labels.npy")
    orig = plyfile.PlyData.read(str(src))
    sub = plyfile.PlyData.read(str(tmp_path / "sub.ply"))
    ov, sv = orig["vertex"], sub["vertex"]
    assert [p.name for p in sv.properties] == [p.name for p in ov.properties]
    assert sv.data.dtype == ov.data.dtype.newbyteorder("<")
    rows = s.source.kept_rows[sel]
    assert res.count == len(rows) == len(sv.data)
    assert sv.data.tobytes() == ov.data[rows].astype(sv.data.dtype).tobytes()
    labels = np.load(tmp_path / "labels.npy")
    assert labels.dtype == bool and labels.shape == (s.source.num_rows,)
    assert np.array_equal(np.flatnonzero(labels), rows)
    again = load_scene(tmp_path / "sub.ply")
    assert np.array_equal(again.means, s.means[sel]) and np.array_equal(again.sh, s.sh[sel])


def test_export_from_ascii_and_with_dropped_rows(tmp_path):
    rows = _gaussian_rows(30, 0, 2, np.random.default_rng(6))
    rows["x"][4] = np.nan
    el = plyfile.PlyElement.describe(rows, "vertex")
    plyfile.PlyData([el], text=True, comments=["made by a test"]).write(str(tmp_path / "a.ply"))
    s = load_scene(tmp_path / "a.ply")
    sel = np.arange(len(s)) % 2 == 0
    export_selection(s, sel, tmp_path / "o.ply")
    out = plyfile.PlyData.read(str(tmp_path / "o.ply"))
    assert not out.text and out.byte_order == "<" and out.comments == ["made by a test"]
    want = rows[s.source.kept_rows[sel]]
    for name in rows.dtype.names:
        assert np.allclose(out["vertex"].data[name], want[name], rtol=1e-6)
    lab = file_labels(s, sel)
    assert lab.shape == (30,) and not lab[4] and lab.sum() == sel.sum()
    with pytest.raises(DivasInputError, match="selection is empty"):
        export_selection(s, np.zeros(len(s), bool), tmp_path / "e.ply")


def _grid(tmp_path, **over):
    d = np.zeros((4, 5, 6), np.float32)
    d[1:3, 2, 3] = 5.0
    arrays = {
        "density": d,
        "aabb": np.array([[0, 0, 0], [6, 5, 4]], float),
        "rgb": np.full((4, 5, 6, 3), 0.5, np.float32),
    }
    arrays.update(over)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    np.savez(tmp_path / "g.npz", **arrays)
    return tmp_path / "g.npz"


def test_density_grid_load_export_and_errors(tmp_path):
    g = load_scene(_grid(tmp_path))
    assert isinstance(g, DensityGrid) and g.shape_xyz == (6, 5, 4)
    assert np.allclose(g.voxel_size, 1.0)
    # no per-cell row index is held for a grid (bookkeeping must not grow with the
    # grid); the rows are every cell in order, made on demand
    assert g.source.kept is None and g.source.dropped == 0
    np.testing.assert_array_equal(g.source.kept_rows, np.arange(g.density.size))
    sel = np.zeros(g.density.shape, bool)
    sel[1, 2, 3] = True
    export_selection(g, sel, tmp_path / "m.npz")
    m = np.load(tmp_path / "m.npz")
    assert m["density"][1, 2, 3] == 5 and m["density"][2, 2, 3] == 0 and m["mask"].sum() == 1
    nan = np.zeros((4, 5, 6), np.float32)
    nan[0, 0, 0], nan[1, 1, 1] = np.nan, 2.0
    assert read_density_grid(_grid(tmp_path, density=nan)).source.dropped_nonfinite == 1
    for over, needle in [
        ({"aabb": None}, "needs keys"),
        ({"density": np.zeros((4, 5))}, "[D,H,W]"),
        ({"aabb": np.array([[0, 0, 0], [0, 1, 1]])}, "max > min"),
        ({"rgb": np.zeros((4, 5, 6))}, "'rgb' must be"),
        ({"density": np.zeros((4, 5, 6))}, "zero everywhere"),
        ({"density": -np.ones((4, 5, 6))}, "negative"),
    ]:
        with pytest.raises(DivasInputError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            load_scene(_grid(tmp_path, **over))
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04garbage")
    with pytest.raises(DivasInputError, match="bad.npz"):
        load_scene(tmp_path / "bad.npz")


def _divas(*args):
    return subprocess.run(
        [sys.executable, "-m", "divas_engine", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
    )


def test_info_cli_json_and_clean_errors(tmp_path, real_data):
    r = _divas("info", real_data / "gaussiansplats3d-lod" / "lod2_tile_0.ply", "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["kind"] == "3dgs" and info["count"] == 6831 and info["sh_degree"] == 3
    assert len(info["bounds_min"]) == 3 and all(
        a <= b for a, b in zip(info["bounds_min"], info["bounds_max"])
    )
    assert info["camera_count"] == 0
    r = _divas("info", _grid(tmp_path), "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["kind"] == "nerf_grid"
    text = _divas("info", real_data / "gaussiansplats3d-lod" / "lod3_tile_0.ply")
    assert text.returncode == 0 and "sh_degree: 3" in text.stdout
    bad = tmp_path / "bad.ply"
    bad.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n"
    )
    r = _divas("info", bad)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert str(bad) in r.stderr and "truncated" in r.stderr


def test_every_documented_subcommand_is_registered():
    """`divas --help` lists every sub-command the README documents (none silently dropped)."""
    r = _divas("--help")
    assert r.returncode == 0
    for cmd in ("info", "generate", "render", "anchors", "segment", "demo", "eval"):
        assert cmd in r.stdout, cmd
    assert _divas("eval", "--help").returncode == 0

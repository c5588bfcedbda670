"""Export with a transform applied (:mod:`divas_engine.transform_export`) and the axis
conversions of :mod:`divas_engine.blender_convention`.

Target: a rotated-and-exported scene renders like the original seen through
the inverse rotation — here the exported file, loaded again, rendered from the camera
carried by the same transform equals the original's render from the original camera.
Tolerance: mean |ΔRGB| ≤ 1e-4 inside the object for float formats (PLY, .splat; only
float rounding), ≤ 2e-3 for the compressed PLY (positions, scales and rotations are
re-quantised to 10–11 bits; .splat: 8-bit rotations, ≤ 3e-3); the single worst pixel ≤ 0.05
(float formats: where two splats' centre depths nearly tie, rounding can swap their blend
order) or ≤ 0.1 (quantised formats). A control run that skips the SH
rotation must fail the same check on an SH-degree-3 capture.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import plyfile
import pytest
from scipy.spatial.transform import Rotation

from divas_engine import load_scene
from divas_engine.blender_convention import AXES, axis_conversion, up_conversion
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.geometry import quat_to_rotmat
from divas_engine.io.splat import SPLAT_DTYPE
from divas_engine.render import make_renderer
from divas_engine.scene import SH_C0
from divas_engine.transform_export import (
    export_transformed_selection,
    transform_frames,
    transform_scene,
)
from divas_engine.views import scene_frame

DATA = Path(__file__).parent / "data"
LOD3 = DATA / "gaussiansplats3d-lod" / "lod3_tile_0.ply"  # 3DGS, SH degree 3 (all zero)
BIKER = DATA / "playcanvas-splats" / "biker.compressed.ply"
PLAYBOT = DATA / "playcanvas-sog" / "playbot_lod3" / "meta.json"  # SH degree 2, real


@pytest.fixture(scope="module")
def playbot_ply(tmp_path_factory) -> Path:
    """The shared SOG playbot (real degree-2 SH) as a 3DGS PLY: SOG itself is not
    re-encoded, and no shared PLY capture has non-zero SH."""
    from divas_engine.io.ply import write_ply_rows

    s = load_scene(PLAYBOT)
    k1 = s.sh.shape[1] - 1
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * k1)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    rows = np.zeros(len(s), [(n, "<f4") for n in names])
    for i, a in enumerate("xyz"):
        rows[a] = s.means[:, i]
    for ch in range(3):
        rows[f"f_dc_{ch}"] = s.sh[:, 0, ch]
        for j in range(k1):
            rows[f"f_rest_{ch * k1 + j}"] = s.sh[:, j + 1, ch]
    o = np.clip(s.opacities.astype(np.float64), 1e-6, 1 - 1e-6)
    rows["opacity"] = np.log(o / (1 - o))
    logs = np.log(np.maximum(np.c_[s.scales, s.scale_n], 1e-12))
    for i in range(3):
        rows[f"scale_{i}"] = logs[:, i]
        rows[f"rot_{i}"] = s.quats[:, i]
    rows["rot_3"] = s.quats[:, 3]
    out = tmp_path_factory.mktemp("playbot") / "playbot.ply"
    write_ply_rows(out, {"vertex": rows})
    return out


@pytest.fixture(scope="module")
def ribs_scene(tmp_path_factory) -> Path:
    """A generated 2DGS scene (SH degree 1) on disk."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs")
    generate_scene("ribs", out, size=5000, seed=0, grid_resolution=16)
    return out / "scene.ply"


def _matrix(scale: float = 1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * Rotation.from_euler("xyz", [40, -25, 70], degrees=True).as_matrix()
    m[:3, 3] = [0.3, -1.2, 2.0]
    return m


@cache
def _camera(path: Path) -> Camera:
    """A 200×150 view of the scene's robust foreground from an oblique direction."""
    fr = scene_frame(load_scene(path))
    eye = fr.center + 2.2 * fr.radius * np.array([0.6, -0.5, 0.62])
    return Camera.look_at(eye, fr.center, [0, 0, 1], width=200, height=150, fx=190.0)


def _moved_camera(cam, m):
    a = m[:3, :3]
    q = a / np.cbrt(np.linalg.det(a))
    c2w = np.eye(4)
    c2w[:3, :3] = q @ cam.c2w[:3, :3]
    c2w[:3, 3] = a @ cam.c2w[:3, 3] + m[:3, 3]
    return cam.with_pose(c2w)


def _render_error(src: Path, out: Path, m) -> tuple[float, float]:
    cam = _camera(src)
    a = make_renderer(load_scene(src), "cpu").render(cam)
    b = make_renderer(load_scene(out), "cpu").render(_moved_camera(cam, m))
    inside = a.alpha > 0.5
    d = np.abs(a.rgb - b.rgb).mean(-1)
    return float(d[inside].mean()), float(d.max())


def _splat_from(path: Path, out: Path) -> Path:
    """A ``.splat`` holding the Gaussians of ``path`` (records built by hand)."""
    rows = plyfile.PlyData.read(str(path))["vertex"].data
    rec = np.zeros(len(rows), SPLAT_DTYPE)
    rec["pos"] = np.stack([rows[k] for k in "xyz"], 1)
    rec["scale"] = np.exp(np.stack([rows[f"scale_{i}"] for i in range(3)], 1))
    rgb = 0.5 + SH_C0 * np.stack([rows[f"f_dc_{i}"] for i in range(3)], 1)
    rec["rgba"][:, :3] = np.clip(rgb * 255, 0, 255)
    rec["rgba"][:, 3] = 255 / (1 + np.exp(-rows["opacity"]))
    q = np.stack([rows[f"rot_{i}"] for i in range(4)], 1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rec["rot"] = np.clip(np.rint(q * 128 + 128), 0, 255)
    rec.tofile(out)
    return out


@pytest.mark.parametrize(
    "case, scale, tol_mean, tol_max",
    [
        ("playbot_ply_sh2", 1.0, 1e-4, 0.05),
        ("playbot_ply_sh2", 1.7, 1e-4, 0.05),
        ("lod3_ply", 0.5, 1e-4, 0.05),
        ("biker_compressed", 1.0, 2e-3, 0.1),
        ("splat", 0.6, 3e-3, 0.1),  # .splat rotations are 8-bit
        ("ribs_2dgs", 1.0, 1e-4, 0.05),
    ],
)
def test_transformed_export_renders_like_the_original_through_the_transform(
    tmp_path, ribs_scene, playbot_ply, case, scale, tol_mean, tol_max
):
    src = {
        "playbot_ply_sh2": playbot_ply,
        "lod3_ply": LOD3,
        "biker_compressed": BIKER,
        "splat": _splat_from(LOD3, tmp_path / "lod3.splat") if case == "splat" else None,
        "ribs_2dgs": ribs_scene,
    }[case]
    m = _matrix(scale)
    scene = load_scene(src)
    out = tmp_path / f"out{''.join(src.suffixes)}"
    res = export_transformed_selection(scene, np.ones(len(scene), bool), out, m)
    assert res.count == len(scene) and res.format == scene.source.format
    assert load_scene(out).source.format == scene.source.format  # the input's own format
    mean, worst = _render_error(src, out, m)
    assert mean <= tol_mean and worst <= tol_max, (mean, worst)


def test_without_sh_rotation_the_same_check_fails(tmp_path, monkeypatch, playbot_ply):
    """Control: the check above detects SH that are not rotated."""
    import divas_engine.transform_export as te

    m = _matrix()
    out = tmp_path / "norot.ply"
    monkeypatch.setattr(te, "transform_sh_rest", lambda rest, matrix: np.asarray(rest).copy())
    scene = load_scene(playbot_ply)
    te.export_transformed_selection(scene, np.ones(len(scene), bool), out, m)
    mean, _ = _render_error(playbot_ply, out, m)
    assert mean > 20 * 1e-4, mean


def test_ply_keeps_every_other_property_and_the_selection(tmp_path):
    scene = load_scene(LOD3)
    sel = np.random.default_rng(0).random(len(scene)) < 0.4
    out = tmp_path / "sel.ply"
    export_transformed_selection(scene, sel, out, _matrix(2.0), labels_path=tmp_path / "l.npy")
    src = plyfile.PlyData.read(str(LOD3))["vertex"].data[scene.source.kept_rows[sel]]
    got = plyfile.PlyData.read(str(out))["vertex"].data
    assert got.dtype.names == src.dtype.names and len(got) == sel.sum()
    for k in ("opacity", "f_dc_0", "f_dc_1", "f_dc_2"):
        np.testing.assert_array_equal(got[k], src[k], err_msg=k)
    np.testing.assert_allclose(got["scale_1"], src["scale_1"] + np.log(2.0), atol=1e-5)
    assert np.load(tmp_path / "l.npy").sum() == sel.sum()


def test_anisotropic_and_mirrored_transforms_give_the_transformed_covariance():
    rng = np.random.default_rng(4)
    n = 500
    q = rng.normal(size=(n, 4))
    s3 = rng.uniform(0.01, 0.3, (n, 3))
    for a in (
        np.array([[2.0, 0.3, 0.0], [0.0, 0.5, 0.2], [0.1, 0.0, 1.3]]),  # shear + stretch
        np.diag([1.0, -1.0, 1.0]) @ Rotation.random(random_state=1).as_matrix(),  # mirror
    ):
        m = np.eye(4)
        m[:3, :3] = a
        r = quat_to_rotmat(q / np.linalg.norm(q, axis=1, keepdims=True))
        q2, s2 = transform_frames(q, s3, m)
        r2 = quat_to_rotmat(q2)
        assert np.allclose(np.linalg.det(r2), 1.0)
        cov = np.einsum("nij,nj,nkj->nik", r, s3**2, r)
        cov2 = np.einsum("nij,nj,nkj->nik", r2, s2**2, r2)
        np.testing.assert_allclose(cov2, a @ cov @ a.T, rtol=1e-5, atol=1e-6)
        # surfels: the disc's tangent frame maps exactly (B' B'ᵀ = A B Bᵀ Aᵀ)
        q2d, s2d = transform_frames(q, s3[:, :2], m)
        b = r[:, :, :2] * s3[:, None, :2]
        b2 = quat_to_rotmat(q2d)[:, :, :2] * s2d[:, None, :]
        np.testing.assert_allclose(
            b2 @ b2.transpose(0, 2, 1), a @ b @ b.transpose(0, 2, 1) @ a.T, atol=1e-6
        )


def test_engine_scene_transform_keeps_the_3dgs_normal_scale():
    scene = load_scene(LOD3)
    m = _matrix(0.5)
    t = transform_scene(scene, m)
    np.testing.assert_allclose(t.scale_n, scene.scale_n * 0.5, rtol=1e-5)
    np.testing.assert_allclose(t.scales, scene.scales * 0.5, rtol=1e-5)


def test_formats_that_cannot_be_reencoded_and_bad_input(tmp_path):
    spz = load_scene(DATA / "playcanvas-splats" / "biker.spz")
    with pytest.raises(DivasInputError, match="spz"):
        export_transformed_selection(spz, np.ones(len(spz), bool), tmp_path / "x.spz", _matrix())
    assert not (tmp_path / "x.spz").exists()
    scene = load_scene(LOD3)
    with pytest.raises(DivasInputError, match="empty"):
        export_transformed_selection(
            scene, np.zeros(len(scene), bool), tmp_path / "e.ply", _matrix()
        )
    with pytest.raises(DivasInputError, match="singular"):
        export_transformed_selection(
            scene, np.ones(len(scene), bool), tmp_path / "s.ply", np.diag([1, 0, 1, 1.0])
        )
    assert list(tmp_path.iterdir()) == []  # nothing half-written


@pytest.mark.parametrize("up", AXES)
def test_axis_conversions_are_rotations(up):
    for fwd in AXES:
        if fwd[-1] == up[-1]:
            with pytest.raises(ValueError):
                axis_conversion(fwd, up)
            continue
        m = axis_conversion(fwd, up)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)
    u = np.zeros(3)
    u["XYZ".index(up[-1])] = -1.0 if up[0] == "-" else 1.0
    np.testing.assert_allclose(up_conversion(u) @ u, [0, 0, 1], atol=1e-12)


def test_colmap_convention_and_tilted_ups():
    np.testing.assert_allclose(axis_conversion("Z", "-Y"), [[1, 0, 0], [0, 0, 1], [0, -1, 0]])
    rng = np.random.default_rng(0)
    for _ in range(20):
        u = rng.normal(size=3)
        r = up_conversion(u)
        np.testing.assert_allclose(r @ (u / np.linalg.norm(u)), [0, 0, 1], atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)


def test_an_anisotropic_export_keeps_every_row_finite(tmp_path):
    """Tiny Gaussians (σ ~ e^-9 beside σ ~ 1) through the eigen path stay finite."""
    scene = load_scene(LOD3)
    m = np.eye(4)
    m[:3, :3] = np.array([[1.0, 0.4, 0.0], [0.0, 2.0, 0.0], [0.3, 0.0, 0.7]], np.float32)
    out = tmp_path / "aniso.ply"
    export_transformed_selection(scene, np.ones(len(scene), bool), out, m)
    back = load_scene(out)
    assert len(back) == len(scene) and back.source.dropped == 0
    np.testing.assert_allclose(back.means, scene.means @ m[:3, :3].T, atol=1e-4)

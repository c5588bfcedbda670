"""Camera type, camera file readers/writers (COLMAP, transforms.json, 3DGS) and Blender math."""

from __future__ import annotations

import json
import math
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from divas_engine.blender_convention import (
    BlenderCameraParams,
    camera_from_blender,
    camera_to_blender,
    project_blender,
    world_to_camera_view,
)
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.io.cameras import detect_camera_format, load_cameras, save_cameras
from divas_engine.io.cameras_json import write_cameras_json
from divas_engine.io.colmap import qvec_to_rotmat, read_colmap, rotmat_to_qvec, write_colmap
from divas_engine.io.transforms_json import image_size, read_transforms_json, write_transforms_json

S = math.sqrt(0.5)


def _rand_cameras(n: int = 4, seed: int = 0) -> list[Camera]:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        w, h = (640, 480) if i % 2 == 0 else (360, 720)
        eye = rng.normal(size=3) * 4
        cams.append(
            Camera.look_at(
                eye,
                rng.normal(size=3) * 0.3,
                [0, 0, 1],
                width=w,
                height=h,
                fx=500 + 37 * i,
                fy=520 - 11 * i,
                cx=w / 2 + 13 * i - 20,
                cy=h / 2 - 7 * i + 5,
                name=f"img_{i:03d}.png",
            )
        )
    # two cameras sharing intrinsics (COLMAP writer dedupes them)
    if n > 1:
        cams.append(cams[0].with_pose(cams[1].c2w, name="img_shared.png"))
    return cams


def _assert_same(a: Camera, b: Camera, tol: float = 1e-9) -> None:
    assert (a.width, a.height, a.name) == (b.width, b.height, b.name)
    np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], atol=tol)
    np.testing.assert_allclose(a.c2w, b.c2w, atol=tol)


def _by_name(cams: list[Camera]) -> dict[str, Camera]:
    return {c.name: c for c in cams}


# --- Camera basics ------------------------------------------------------------------
def test_project_unproject_round_trip():
    cam = _rand_cameras(1)[0]
    rng = np.random.default_rng(1)
    uv = rng.uniform([0, 0], [cam.width, cam.height], size=(100, 2))
    z = rng.uniform(0.5, 20, size=100)
    uv2, z2 = cam.project(cam.unproject(uv, z))
    np.testing.assert_allclose(uv2, uv, atol=1e-9)
    np.testing.assert_allclose(z2, z, atol=1e-9)
    d = cam.ray_directions(uv)
    pts = cam.unproject(uv, z)
    np.testing.assert_allclose(np.cross(pts - cam.center, d), 0, atol=1e-9)


def test_scaled_keeps_half_pixel_centres():
    cam = Camera(640, 480, 500, 510, 317.0, 245.5, name="c")
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    pts = cam.unproject(np.array([[10.0, 20.0], [600.0, 400.0]]), np.array([2.0, 3.0]))
    np.testing.assert_allclose(half.project(pts)[0], cam.project(pts)[0] * 0.5, atol=1e-9)
    # pixel (0,0) of the half image covers pixels (0..1, 0..1) of the full one: its centre
    # (0.5, 0.5) is the mean of full-res centres 0.5 and 1.5, i.e. (1, 1)
    p = cam.unproject(np.array([[1.0, 1.0]]), np.array([5.0]))
    np.testing.assert_allclose(half.project(p)[0], [[0.5, 0.5]], atol=1e-9)


def test_pixels_to_maps_full_pixels_onto_the_render():
    cam = Camera(641, 479, 500, 510, 317.0, 245.5, name="c")
    small = cam.scaled(0.37)  # rounded size: the scale per axis is w'/w, h'/h
    assert (small.width, small.height) == (237, 177)
    uv = np.array([[10.25, 20.5], [600.0, 400.75], [0.0, 0.0]])
    pts = cam.unproject(uv, np.array([2.0, 3.0, 1.5]))
    np.testing.assert_allclose(cam.pixels_to(small, uv), small.project(pts)[0], atol=1e-9)
    np.testing.assert_array_equal(
        cam.pixels_to(small, (10.25, 20.5)), [10.25 * (237 / 641), 20.5 * (177 / 479)]
    )
    np.testing.assert_allclose(small.pixels_to(cam, cam.pixels_to(small, uv)), uv, atol=1e-12)
    assert cam.pixels_to(small, np.zeros((0, 2))).shape == (0, 2)


def test_look_at_target_at_principal_point():
    cam = Camera.look_at(
        [3, -2, 1], [0.5, 0.2, -0.1], [0, 0, 1], width=800, height=600, fx=700, cx=390.0, cy=310.0
    )
    uv, z = cam.project(np.array([[0.5, 0.2, -0.1]]))
    np.testing.assert_allclose(uv, [[390.0, 310.0]], atol=1e-9)
    assert z[0] > 0
    assert cam.up @ np.array([0, 0, 1.0]) > 0  # image-up follows world +z


def test_dict_round_trip_and_invalid():
    cam = _rand_cameras(1)[0]
    _assert_same(Camera.from_dict(json.loads(json.dumps(cam.to_dict()))), cam, 0)
    with pytest.raises(ValueError, match="focal"):
        Camera(100, 100, 0.0, 100, 50, 50)
    with pytest.raises(ValueError, match="focal"):
        Camera(100, 100, 100, -1.0, 50, 50)
    with pytest.raises(ValueError, match="unknown camera keys"):
        Camera.from_dict({**cam.to_dict(), "fov": 1})
    with pytest.raises(ValueError, match="rotation"):
        Camera(100, 100, 100, 100, 50, 50, np.diag([1.0, 1.0, -1.0, 1.0]))


def test_quaternion_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        np.testing.assert_allclose(rotmat_to_qvec(qvec_to_rotmat(q)), q, atol=1e-12)
    for r in (np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):
        np.testing.assert_allclose(qvec_to_rotmat(rotmat_to_qvec(r)), r, atol=1e-12)


# --- COLMAP -------------------------------------------------------------------------
@pytest.mark.parametrize("binary", [True, False])
def test_colmap_writer_round_trip(tmp_path, binary):
    cams = _rand_cameras()
    d = write_colmap(tmp_path / "m", cams, binary=binary)
    ext = ".bin" if binary else ".txt"
    assert {p.name for p in d.iterdir()} == {f"cameras{ext}", f"images{ext}", f"points3D{ext}"}
    got = read_colmap(d)
    assert [c.name for c in got] == sorted(c.name for c in cams)
    for name, c in _by_name(cams).items():
        _assert_same(_by_name(got)[name], c, 1e-9)
    n_cam_lines = (
        [ln for ln in (d / "cameras.txt").read_text().splitlines() if ln and not ln.startswith("#")]
        if not binary
        else None
    )
    if n_cam_lines is not None:
        assert len(n_cam_lines) == len(cams) - 1  # shared intrinsics written once


# A tiny model written by hand. Image 1: 90° about z, q = (√½, 0, 0, √½), t = (1, 2, 3):
# R_w2c = [[0,-1,0],[1,0,0],[0,0,1]], so c2w rotation = Rᵀ = [[0,1,0],[-1,0,0],[0,0,1]] and
# centre = -Rᵀ t = -(2, -1, 3) = (-2, 1, -3). Image 2: identity, t = (0, 0, 4): centre (0, 0, -4).
HAND_C2W_A = np.array([[0, 1, 0, -2], [-1, 0, 0, 1], [0, 0, 1, -3], [0, 0, 0, 1.0]])
HAND_C2W_B = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -4], [0, 0, 0, 1.0]])

HAND_CAMERAS_TXT = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
3 PINHOLE 640 480 500 510 320.5 240.25
7 SIMPLE_PINHOLE 200 100 150 99.5 50
"""
HAND_IMAGES_TXT = f"""# Image list with two lines of data per image:
#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME
#   POINTS2D[] as (X, Y, POINT3D_ID)
1 {S!r} 0 0 {S!r} 1 2 3 3 a.jpg
10.5 20.25 -1 30 40 7
2 1 0 0 0 0 0 4 7 b.jpg

"""


def _check_hand_model(cams: list[Camera]) -> None:
    a, b = cams
    assert (a.name, a.width, a.height, a.fx, a.fy, a.cx, a.cy) == (
        "a.jpg",
        640,
        480,
        500,
        510,
        320.5,
        240.25,
    )
    assert (b.name, b.width, b.height, b.fx, b.fy, b.cx, b.cy) == (
        "b.jpg",
        200,
        100,
        150,
        150,
        99.5,
        50,
    )
    np.testing.assert_allclose(a.c2w, HAND_C2W_A, atol=1e-12)
    np.testing.assert_allclose(b.c2w, HAND_C2W_B, atol=1e-12)
    # world origin seen by camera a at x_cam = t = (1, 2, 3)
    uv, z = a.project(np.zeros((1, 3)))
    np.testing.assert_allclose(uv, [[500 / 3 + 320.5, 510 * 2 / 3 + 240.25]])
    assert z[0] == pytest.approx(3.0)


def test_colmap_text_by_hand(tmp_path):
    (tmp_path / "cameras.txt").write_text(HAND_CAMERAS_TXT)
    (tmp_path / "images.txt").write_text(HAND_IMAGES_TXT)
    _check_hand_model(read_colmap(tmp_path))


def _hand_bin(tmp_path: Path) -> Path:
    cb = struct.pack("<Q", 2)
    cb += struct.pack("<IiQQ", 3, 1, 640, 480) + struct.pack("<4d", 500, 510, 320.5, 240.25)
    cb += struct.pack("<IiQQ", 7, 0, 200, 100) + struct.pack("<3d", 150, 99.5, 50)
    ib = struct.pack("<Q", 2)
    ib += struct.pack("<I", 1) + struct.pack("<4d", S, 0, 0, S) + struct.pack("<3d", 1, 2, 3)
    ib += struct.pack("<I", 3) + b"a.jpg\x00" + struct.pack("<Q", 2)
    ib += struct.pack("<ddq", 10.5, 20.25, -1) + struct.pack("<ddq", 30, 40, 7)
    ib += struct.pack("<I", 2) + struct.pack("<4d", 1, 0, 0, 0) + struct.pack("<3d", 0, 0, 4)
    ib += struct.pack("<I", 7) + b"b.jpg\x00" + struct.pack("<Q", 0)
    d = tmp_path / "sparse" / "0"
    d.mkdir(parents=True)
    (d / "cameras.bin").write_bytes(cb)
    (d / "images.bin").write_bytes(ib)
    return d


def test_colmap_binary_by_hand(tmp_path):
    d = _hand_bin(tmp_path)
    _check_hand_model(read_colmap(d))
    _check_hand_model(load_cameras(tmp_path))  # found under sparse/0


def test_colmap_distortion_warns_and_unsupported_model(tmp_path):
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 1 1 x.png\n\n2 1 0 0 0 0 0 2 2 y.png\n")
    (tmp_path / "cameras.txt").write_text(
        "1 SIMPLE_RADIAL 100 80 90 50 40 0.0\n2 OPENCV 100 80 90 91 50 40 0.01 0 0 0\n"
    )
    with pytest.warns(UserWarning, match=r"distortion of camera\(s\) 2 \(OPENCV\) is ignored"):
        cams = read_colmap(tmp_path)
    assert [(c.fx, c.fy) for c in cams] == [(90, 90), (90, 91)]
    (tmp_path / "cameras.txt").write_text(
        "1 SIMPLE_RADIAL 100 80 90 50 40 0.0\n2 RADIAL 100 80 90 50 40 0 0\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zero distortion: no warning
        read_colmap(tmp_path)
    (tmp_path / "cameras.txt").write_text(
        "1 PINHOLE 100 80 90 90 50 40\n2 OPENCV_FISHEYE 100 80 90 90 50 40 0 0 0 0\n"
    )
    with pytest.raises(DivasInputError, match="OPENCV_FISHEYE is not supported") as e:
        read_colmap(tmp_path)
    assert e.value.source.endswith("cameras.txt")


def test_colmap_bad_input(tmp_path):
    d = _hand_bin(tmp_path)
    good = (d / "images.bin").read_bytes()
    for cut in (4, 40, len(good) - 30, len(good) - 3):
        (d / "images.bin").write_bytes(good[:cut])
        with pytest.raises(DivasInputError, match="truncated") as e:
            read_colmap(d)
        assert e.value.source.endswith("images.bin")
    (d / "images.bin").write_bytes(good + b"\0")
    with pytest.raises(DivasInputError, match="trailing bytes"):
        read_colmap(d)
    (d / "images.bin").write_bytes(good)
    cams = (d / "cameras.bin").read_bytes()
    (d / "cameras.bin").write_bytes(cams[:-8])
    with pytest.raises(DivasInputError, match="truncated") as e:
        read_colmap(d)
    assert e.value.source.endswith("cameras.bin")

    t = tmp_path / "txt"
    t.mkdir()
    (t / "cameras.txt").write_text("3 PINHOLE 640 480 500 510 320 240\n")
    (t / "images.txt").write_text("1 1 0 0 0 0 0 0 5 a.png\n\n")
    with pytest.raises(DivasInputError, match="refers to camera 5") as e:  # mismatched ids
        read_colmap(t)
    assert e.value.source.endswith("images.txt")
    (t / "images.txt").write_text("1 1 0 0 0 0 0 0 3 a.png\n\n")
    (t / "cameras.txt").write_text("3 PINHOLE 640 480 0 510 320 240\n")
    with pytest.raises(DivasInputError, match="focal length fx=0.0") as e:
        read_colmap(t)
    assert e.value.source.endswith("cameras.txt")
    (t / "cameras.txt").write_text("3 PINHOLE 640 480 500 510 320\n")
    with pytest.raises(DivasInputError, match="line 1: camera model PINHOLE takes 4"):
        read_colmap(t)
    (t / "cameras.txt").write_text("3 PINHOLE 640 480 500 510 320 240\n")
    (t / "images.txt").write_text("1 1 0 0 zero 0 0 0 3 a.png\n\n")
    with pytest.raises(DivasInputError, match="line 1: expected 'IMAGE_ID"):
        read_colmap(t)
    (t / "images.txt").write_text("1 0 0 0 0 0 0 0 3 a.png\n\n")
    with pytest.raises(DivasInputError, match="invalid rotation quaternion"):
        read_colmap(t)


# --- transforms.json -------------------------------------------------------------------
def _write_image(path: Path, w: int, h: int) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.full((h, w, 3), 128, np.uint8))


def test_image_size_headers(tmp_path):
    for ext in (".png", ".jpg", ".bmp"):  # PNG/JPEG parsed, BMP through OpenCV
        _write_image(tmp_path / f"i{ext}", 37, 21)
        assert image_size(tmp_path / f"i{ext}") == (37, 21)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    assert image_size(tmp_path / "bad.png") is None
    assert image_size(tmp_path / "missing.png") is None


def test_transforms_opengl_flip_by_hand(tmp_path):
    # OpenGL camera at (0, 0, 5), identity rotation: looks down world −z, i.e. at the origin
    m = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]]
    p = tmp_path / "transforms.json"
    p.write_text(
        json.dumps(
            {
                "fl_x": 400,
                "fl_y": 410,
                "cx": 330.5,
                "cy": 235.25,
                "w": 640,
                "h": 480,
                "frames": [{"file_path": "./a.png", "transform_matrix": m}],
            }
        )
    )
    (cam,) = read_transforms_json(p)
    uv, z = cam.project(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]))
    np.testing.assert_allclose(uv[0], [330.5, 235.25], atol=1e-12)
    assert z[0] == pytest.approx(5.0)
    assert uv[1, 0] > 330.5 and uv[1, 1] == pytest.approx(235.25)  # +x world: right
    assert uv[2, 1] < 235.25 and uv[2, 0] == pytest.approx(330.5)  # +y world (GL up): up
    np.testing.assert_allclose(cam.c2w[:3, :3], np.diag([1.0, -1, -1]))
    assert cam.name == "./a.png"


def test_transforms_camera_angle_and_image_header(tmp_path):
    # NeRF-synthetic style: only camera_angle_x, no w/h, file_path without extension
    _write_image(tmp_path / "train" / "r_0.png", 80, 60)
    _write_image(tmp_path / "train" / "r_1.jpg", 80, 60)
    m = np.eye(4).tolist()
    p = tmp_path / "transforms_train.json"
    p.write_text(
        json.dumps(
            {
                "camera_angle_x": 0.6911112070083618,
                "frames": [
                    {"file_path": "./train/r_0", "transform_matrix": m},
                    {"file_path": "./train/r_1", "transform_matrix": m, "camera_angle_y": 0.5},
                ],
            }
        )
    )
    a, b = read_transforms_json(p)
    f = 0.5 * 80 / math.tan(0.5 * 0.6911112070083618)
    assert (a.width, a.height, a.cx, a.cy) == (80, 60, 40, 30)
    assert a.fx == pytest.approx(f) and a.fy == pytest.approx(f)
    assert b.fy == pytest.approx(0.5 * 60 / math.tan(0.25)) and b.fx == pytest.approx(f)
    # per-frame override of fl_x and size; the frame's own w/h win
    p.write_text(
        json.dumps(
            {
                "fl_x": 100,
                "w": 80,
                "h": 60,
                "frames": [
                    {"file_path": "x", "transform_matrix": m},
                    {
                        "file_path": "y",
                        "transform_matrix": m,
                        "fl_x": 50,
                        "fl_y": 55,
                        "w": 40,
                        "h": 30,
                    },
                ],
            }
        )
    )
    a, b = read_transforms_json(p)
    assert (a.fx, a.fy, a.width, a.cx) == (100, 100, 80, 40)
    assert (b.fx, b.fy, b.width, b.height, b.cx, b.cy) == (50, 55, 40, 30, 20, 15)


def test_transforms_round_trip_and_bad_input(tmp_path):
    cams = _rand_cameras()
    p = tmp_path / "transforms.json"
    write_transforms_json(p, cams)
    for a, b in zip(read_transforms_json(p), cams):
        _assert_same(a, b, 1e-9)
    shared = [c.with_pose(cams[i].c2w, name=f"f{i}") for i, c in enumerate([cams[0]] * 3)]
    write_transforms_json(p, shared)
    data = json.loads(p.read_text())
    assert data["fl_x"] == cams[0].fx and "fl_x" not in data["frames"][0]
    for a, b in zip(read_transforms_json(p), shared):
        _assert_same(a, b, 1e-9)

    m = np.eye(4).tolist()
    bad = {
        "{not json": "not valid JSON",
        json.dumps({"frames": []}): "non-empty 'frames'",
        json.dumps(
            {"frames": [{"file_path": "nope", "transform_matrix": m, "camera_angle_x": 1.0}]}
        ): "image 'nope' was not found",
        json.dumps({"w": 10, "h": 10, "frames": [{"transform_matrix": m}]}): "no focal length",
        json.dumps(
            {"w": 10, "h": 10, "fl_x": 0, "frames": [{"transform_matrix": m}]}
        ): "focal length fx=0.0",
        json.dumps(
            {"w": 10, "h": 10, "camera_angle_x": 0, "frames": [{"transform_matrix": m}]}
        ): "camera_angle_x=0.0",
        json.dumps(
            {"w": 10, "h": 10, "fl_x": 5, "frames": [{"file_path": "a"}]}
        ): "missing key 'transform_matrix'",
        json.dumps(
            {"w": 10, "h": 10, "fl_x": 5, "frames": [{"transform_matrix": [[1, 0]]}]}
        ): "transform_matrix must be 4x4",
        json.dumps(
            {
                "w": 10,
                "h": 10,
                "fl_x": 5,
                "camera_model": "OPENCV_FISHEYE",
                "frames": [{"transform_matrix": m}],
            }
        ): "not supported",
    }
    for text, msg in bad.items():
        p.write_text(text)
        with pytest.raises(DivasInputError, match=msg) as e:
            read_transforms_json(p)
        assert e.value.source == str(p)
    p.write_text(
        json.dumps({"w": 10, "h": 10, "fl_x": 5, "k1": 0.1, "frames": [{"transform_matrix": m}]})
    )
    with pytest.warns(UserWarning, match="distortion of 1 frame"):
        read_transforms_json(p)


# --- auto-detect -------------------------------------------------------------------------
def test_load_cameras_autodetect(tmp_path):
    cams = _rand_cameras(3)
    (tmp_path / "g").mkdir()
    write_cameras_json(tmp_path / "g" / "cameras.json", cams)
    write_transforms_json(tmp_path / "t.json", cams)
    write_colmap(tmp_path / "scene" / "sparse" / "0", cams)
    write_colmap(tmp_path / "scene2" / "sparse", cams, binary=False)
    write_colmap(tmp_path / "model", cams)
    cases = {
        tmp_path / "g" / "cameras.json": "cameras_json",
        tmp_path / "g": "cameras_json",
        tmp_path / "t.json": "transforms_json",
        tmp_path / "scene": "colmap",
        tmp_path / "scene2": "colmap",
        tmp_path / "model": "colmap",
        tmp_path / "model" / "images.bin": "colmap",
    }
    for path, fmt in cases.items():
        assert detect_camera_format(path)[0] == fmt, path
        got = _by_name(load_cameras(path))
        for c in cams:
            _assert_same(got[c.name], c, 1e-9)

    (tmp_path / "x.json").write_text(json.dumps({"cameras": []}))
    (tmp_path / "bad.json").write_text("[1, 2")
    (tmp_path / "empty").mkdir()
    (tmp_path / "model.ply").write_text("ply")
    for path, msg in [
        (tmp_path / "x.json", "unknown camera format"),
        (tmp_path / "bad.json", "not valid JSON"),
        (tmp_path / "empty", "unknown camera format"),
        (tmp_path / "model.ply", "unknown camera format"),
        (tmp_path / "missing", "does not exist"),
    ]:
        with pytest.raises(DivasInputError, match=msg) as e:
            load_cameras(path)
        assert e.value.source == str(path)


def test_save_cameras_by_path(tmp_path):
    cams = _rand_cameras(2)
    for name, fmt in [
        ("cams.json", "cameras_json"),
        ("transforms.json", "transforms_json"),
        ("colmap_out", "colmap"),
    ]:
        out = save_cameras(tmp_path / name, cams)
        assert detect_camera_format(out)[0] == fmt
    out = save_cameras(tmp_path / "txt_model", cams, fmt="colmap_text")
    assert (out / "cameras.txt").is_file()
    with pytest.raises(DivasInputError, match="cannot choose"):
        save_cameras(tmp_path / "cams.yaml", cams)


# --- Blender convention (pure math; the bpy cross-check is in test_blender_convention_bpy) ---
def _blender_cams() -> list[Camera]:
    rng = np.random.default_rng(7)
    specs = [
        (640, 480, 500, 500, 320, 240),
        (640, 480, 520, 480, 300.5, 250.25),
        (480, 640, 450, 530, 250, 300),
        (300, 900, 400, 700, 120, 500),
        (1000, 1000, 800, 600, 480, 530),
    ]
    return [
        Camera.look_at(
            rng.normal(size=3) * 3,
            rng.normal(size=3) * 0.2,
            [0, 0, 1],
            width=w,
            height=h,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            name=f"b{i}",
        )
        for i, (w, h, fx, fy, cx, cy) in enumerate(specs)
    ]


def test_blender_round_trip_and_projection():
    rng = np.random.default_rng(8)
    for cam in _blender_cams():
        p = camera_to_blender(cam)
        assert min(p.pixel_aspect_x, p.pixel_aspect_y) == 1.0
        assert p.sensor_fit == (
            "HORIZONTAL" if cam.width / cam.fx >= cam.height / cam.fy else "VERTICAL"
        )
        _assert_same(camera_from_blender(p), cam, 1e-9)
        uv = rng.uniform(
            [-0.5 * cam.width, -0.5 * cam.height], [1.5 * cam.width, 1.5 * cam.height], (200, 2)
        )
        pts = cam.unproject(uv, rng.uniform(0.2, 30, 200))
        uvb, zb = project_blender(p, pts)
        np.testing.assert_allclose(uvb, uv, atol=1e-7)
        np.testing.assert_allclose(zb, cam.project(pts)[1], atol=1e-9)
        # Blender camera axes: looks down local −z, local +y is image up
        np.testing.assert_allclose(-p.matrix_world[:3, 2], cam.forward, atol=1e-12)
        np.testing.assert_allclose(p.matrix_world[:3, 1], cam.up, atol=1e-12)


def test_blender_semantics_by_hand():
    eye = np.eye(4)
    # landscape, horizontal fit: fx = lens·W/sensor_w, shift in units of W, y shift too
    p = BlenderCameraParams(eye, 50.0, 36.0, 24.0, "HORIZONTAL", 0.1, 0.05, 1000, 500)
    c = camera_from_blender(p)
    assert (c.fx, c.fy, c.cx, c.cy) == (pytest.approx(50 * 1000 / 36),) * 2 + (400.0, 300.0)
    # portrait, AUTO: the vertical side is fitted but sensor_WIDTH sets the focal, and both
    # shifts are fractions of the (vertical) fitted side
    p = BlenderCameraParams(eye, 50.0, 36.0, 24.0, "AUTO", 0.1, -0.1, 500, 1000)
    c = camera_from_blender(p)
    assert p.fit == "VERTICAL" and c.fx == pytest.approx(50 * 1000 / 36)
    assert (c.cx, c.cy) == (pytest.approx(250 - 100), pytest.approx(500 - 100))
    # pixel aspect 2:1 (y/x): ycor = 2, fx = 2·fy; resolution percentage scales everything
    p = BlenderCameraParams(
        eye,
        36.0,
        36.0,
        24.0,
        "HORIZONTAL",
        0.0,
        0.0,
        400,
        200,
        pixel_aspect_x=1.0,
        pixel_aspect_y=2.0,
        resolution_percentage=50,
    )
    c = camera_from_blender(p)
    assert (c.width, c.height, c.fx, c.fy) == (200, 100, pytest.approx(200.0), pytest.approx(100.0))
    # the optical axis point projects to the principal point; (0, 0) is bottom-left
    ndc = world_to_camera_view(p, np.array([[0, 0, -3.0], [0, 0, 0.0]]))
    np.testing.assert_allclose(ndc, [[0.5, 0.5, 3.0], [0.5, 0.5, 0.0]])
    q = BlenderCameraParams(eye, 50.0, 36.0, 24.0, "HORIZONTAL", 0.0, 0.0, 100, 100)
    ndc = world_to_camera_view(q, np.array([[-0.36, -0.36, -1.0]]))  # bottom-left corner
    np.testing.assert_allclose(ndc[:, :2], [[0.0, 0.0]], atol=1e-12)
    # object scale in matrix_world is ignored
    scaled = BlenderCameraParams(
        np.diag([2.0, 3.0, 4.0, 1.0]), 50.0, 36.0, 24.0, "AUTO", 0, 0, 100, 100
    )
    np.testing.assert_allclose(camera_from_blender(scaled).c2w, np.diag([1.0, -1, -1, 1]))
    with pytest.raises(ValueError, match="sensor_fit"):
        BlenderCameraParams(eye, 50.0, 36.0, 24.0, "FIT", 0, 0, 10, 10)


def test_camera_near_clip_is_carried_and_validated():
    """``Camera.near`` (a camera's own clip, like Blender's clip_start) survives every
    derived camera and the dict round trip, and the renderer's near wins when larger."""
    cam = _rand_cameras(1)[0].with_near(0.25)
    assert cam.near == 0.25
    assert cam.scaled(0.5).near == 0.25 and cam.with_pose(np.eye(4)).near == 0.25
    back = Camera.from_dict(json.loads(json.dumps(cam.to_dict())))
    assert back.near == 0.25
    assert "near" not in cam.with_near(0.0).to_dict()  # old files stay byte-identical
    assert Camera.from_dict(cam.with_near(0.0).to_dict()).near == 0.0
    assert cam.clip_near(0.01) == 0.25 and cam.clip_near(0.5) == 0.5
    assert (
        Camera.look_at([0, 0, 0], [0, 0, 1], [0, -1, 0], width=8, height=8, fx=8, near=0.3).near
        == 0.3
    )
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="near clip"):
            cam.with_near(bad)


def test_in_image_by_hand():
    """Points in front of ``near`` with finite pixels inside [0, W) × [0, H) only."""
    cam = Camera.look_at(
        np.array([0.0, 0.0, -2.0]),
        np.zeros(3),
        np.array([0.0, 1.0, 0.0]),
        width=4,
        height=3,
        fx=4.0,
    )
    uv = np.array(
        [[0.0, 0.0], [3.99, 2.99], [4.0, 1.0], [1.0, 3.0], [-0.01, 1], [np.nan, 1], [1, 1]]
    )
    z = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.5])
    assert cam.in_image(uv, z).tolist() == [True, True, False, False, False, False, True]
    assert cam.in_image(uv, z, near=0.5).tolist()[-1] is False

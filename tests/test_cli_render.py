"""``divas render``: the three camera options, the files it writes, bad input → exit 2."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.camera import Camera
from divas_engine.cli import main
from divas_engine.cli.render import orbit_camera
from divas_engine.io.cameras_json import write_cameras_json
from divas_engine.io.density_grid import write_density_grid
from divas_engine.io.ply import write_surfel_ply
from divas_engine.render import make_renderer

from .reference_render import random_density_grid, random_surfel_scene

CAM = Camera.look_at([0.1, 0.0, -0.2], [0, 0, 4], [0, -1, 0], width=48, height=36, fx=40)
CHANNELS = ("rgb", "alpha", "D_min", "D_ref", "D_max", "D_mw", "D_exp", "N_samp")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("render_cli")
    write_surfel_ply(d / "scene.ply", random_surfel_scene(600, seed=5))
    write_cameras_json(d / "cameras.json", [CAM, CAM.scaled(0.5)])
    write_density_grid(d / "grid.npz", random_density_grid(seed=2))
    return d


def test_render_from_camera_file(files, capsys):
    out = files / "out" / "view"
    assert (
        main(
            [
                "render",
                str(files / "scene.ply"),
                "--cameras",
                str(files / "cameras.json"),
                "--index",
                "0",
                "--out",
                str(out),
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    z = np.load(str(out) + ".npz")
    assert set(CHANNELS) <= set(z.files)
    want = make_renderer(load_scene(files / "scene.ply"), "cpu").render(CAM)
    for k in CHANNELS:
        assert np.array_equal(z[k], getattr(want, k)), k
    rgb = cv2.imread(str(out) + ".png")
    assert rgb.shape == (36, 48, 3)
    dmin = cv2.imread(str(out) + "_D_min.png")
    assert np.all(dmin[want.D_min == 0] == 0) and dmin[want.D_min > 0].any()
    for k in ("D_ref", "D_max", "D_mw", "D_exp", "N_samp"):
        assert (files / "out" / f"view_{k}.png").is_file()
    assert "view.npz" in capsys.readouterr().out


def test_render_camera_json_scale_and_grid(files, tmp_path):
    cam_json = json.dumps(CAM.to_dict())
    assert (
        main(
            [
                "render",
                str(files / "grid.npz"),
                "--camera-json",
                cam_json,
                "--scale",
                "0.5",
                "--out",
                str(tmp_path / "g"),
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    z = np.load(tmp_path / "g.npz")
    assert z["rgb"].shape == (18, 24, 3) and z["N_samp"].dtype == np.int32
    assert np.array_equal(z["D_ref"], z["D_exp"])
    (tmp_path / "cam.json").write_text(cam_json)
    assert (
        main(
            [
                "render",
                str(files / "scene.ply"),
                "--camera-json",
                str(tmp_path / "cam.json"),
                "--out",
                str(tmp_path / "s"),
                "--device",
                "cpu",
            ]
        )
        == 0
    )


def test_render_orbit(files, tmp_path):
    scene = load_scene(files / "scene.ply")
    cam = orbit_camera(scene, 30.0, 20.0)
    assert (cam.width, cam.height, cam.fx) == (640, 480, 600.0)
    c = np.median(scene.means, axis=0)
    r90 = np.percentile(np.linalg.norm(scene.means - c, axis=1), 90)
    assert np.isclose(np.linalg.norm(cam.center - c), 2.5 * r90)
    assert np.allclose(cam.forward, (c - cam.center) / np.linalg.norm(c - cam.center))
    assert (
        main(
            [
                "render",
                str(files / "scene.ply"),
                "--orbit",
                "30,20",
                "--scale",
                "0.25",
                "--out",
                str(tmp_path / "o"),
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    assert np.load(tmp_path / "o.npz")["alpha"].max() > 0.5


@pytest.mark.parametrize(
    "extra, msg",
    [
        (["--cameras", "CAMS", "--index", "7"], "out of range"),
        (["--cameras", "CAMS"], "--index"),
        (["--camera-json", "{not json"], "not valid JSON"),
        (["--camera-json", '{"width": 10}'], "missing"),
        (["--camera-json", "[1, 2]"], "one JSON object"),
        (["--orbit", "10"], "--orbit"),
        (["--orbit", "0,0", "--scale", "-1"], "--scale"),
    ],
)
def test_bad_input_exits_2(files, tmp_path, capsys, extra, msg):
    extra = [str(files / "cameras.json") if a == "CAMS" else a for a in extra]
    rc = main(
        [
            "render",
            str(files / "scene.ply"),
            *extra,
            "--out",
            str(tmp_path / "x"),
            "--device",
            "cpu",
        ]
    )
    assert rc == 2
    assert msg in capsys.readouterr().err

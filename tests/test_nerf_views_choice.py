"""Which renderer draws an instant-ngp snapshot's views: the network or the marched grid,
chosen by ``RenderConfig.nerf_network`` (None: the network on CUDA, the grid on a CPU), by
``divas segment --network-views`` / ``--grid-views`` and by the add-on's NeRF Views."""

from __future__ import annotations

import json

import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.io.instant_ngp import write_ngp_document
from divas_engine.render import RenderConfig, make_renderer, network_views
from divas_engine.render.ngp_renderer import NgpRenderer
from divas_engine.scene import DensityGrid
from divas_engine.segment_request import SegmentRequest
from divas_engine.synthetic.ngp_snapshot import snapshot_of_grid

from .ngp_cases import look_at_camera

CAM = look_at_camera([2.2, -2.6, 1.4], [0, 0, 0], size=(64, 48), f=56.0, name="t0")
#: the red box's centre (world), where the segment tests click
RED = np.array([[-0.375, 0.0, -0.3125]])
#: world boxes (x, y, z) of the red and the blue box
RED_BOX = np.array([[-0.6875, -0.5, -0.625], [-0.0625, 0.5, 0.0]])
BLUE_BOX = np.array([[0.0, -0.375, 0.125], [0.6875, 0.25, 0.6875]])


@pytest.fixture(scope="module")
def snapshot(tmp_path_factory):
    """Two boxes (red, blue) as a snapshot whose network reproduces them."""
    n = 32
    dens = np.zeros((n, n, n), np.float32)
    rgb = np.zeros((n, n, n, 3), np.float32)
    dens[6:16, 8:24, 5:15] = 60.0  # z, y, x: the red box
    rgb[6:16, 8:24, 5:15] = (0.9, 0.2, 0.1)
    dens[18:27, 10:20, 16:27] = 60.0
    rgb[18:27, 10:20, 16:27] = (0.1, 0.3, 0.9)
    src = DensityGrid(dens, np.array([[-1.0, -1, -1], [1, 1, 1]]), rgb)
    doc = snapshot_of_grid(src, [CAM], network=True, network_resolution=32)
    p = tmp_path_factory.mktemp("snap") / "boxes.ingp"
    write_ngp_document(p, doc, True)
    return p


def _inside(g, box, margin=0.1) -> np.ndarray:
    """Occupied cells of ``g`` whose centres lie in ``box`` grown by ``margin``."""
    idx = np.argwhere(g.density > 0)
    c = g.aabb[0] + (idx[:, ::-1] + 0.5) * g.voxel_size
    inside = np.all((c >= box[0] - margin) & (c <= box[1] + margin), axis=1)
    out = np.zeros(g.density.shape, bool)
    out[tuple(idx[inside].T)] = True
    return out


def test_the_choice_follows_the_config_else_the_device():
    assert network_views(RenderConfig(nerf_network=True), "cpu")
    assert not network_views(RenderConfig(nerf_network=False), "cpu")
    assert not network_views(RenderConfig(), "cpu") and not network_views(None, "cpu")


def test_a_cpu_marches_the_grid_unless_asked_for_the_network(snapshot):
    g = load_scene(snapshot)
    assert not isinstance(make_renderer(g, "cpu"), NgpRenderer)
    forced = make_renderer(g, "cpu", RenderConfig(nerf_network=True))
    assert isinstance(forced, NgpRenderer)
    a = make_renderer(g, "cpu").render(CAM)
    b = forced.render(CAM)
    ma, mb = a.alpha > 0.5, b.alpha > 0.5  # the same boxes, drawn two ways
    assert ma.any() and (ma & mb).sum() / (ma | mb).sum() > 0.8
    assert not np.array_equal(a.rgb, b.rgb)


def test_segment_request_maps_its_flags():
    base = dict(scene="s.ingp", prompts="p.json")
    assert SegmentRequest(**base).nerf_network is None
    assert SegmentRequest(**base, grid_views=True).nerf_network is False
    assert SegmentRequest(**base, network_views=True).nerf_network is True
    with pytest.raises(DivasInputError, match="exclude each other"):
        SegmentRequest(**base, grid_views=True, network_views=True).check()
    row = SegmentRequest.from_mapping({**base, "network_views": True})
    assert row.nerf_network is True
    with pytest.raises(DivasInputError, match="true or false"):
        SegmentRequest.from_mapping({**base, "network_views": "yes"})


@pytest.mark.parametrize("flag", [None, "--network-views", "--grid-views"])
def test_segment_runs_each_way(snapshot, tmp_path, flag):
    from divas_engine.cli import main

    g = load_scene(snapshot)
    np.save(tmp_path / "gt.npy", _inside(g, RED_BOX))
    uv, _ = CAM.project(RED)
    clicks = [{"xy": uv[0].tolist()}]
    prompts = {"version": 1, "anchors": [{"training_camera": "t0", "clicks": clicks}]}
    (tmp_path / "p.json").write_text(json.dumps(prompts))
    out = tmp_path / "sel.ingp"
    argv = ["segment", str(snapshot), "--prompts", str(tmp_path / "p.json"), "--out", str(out)]
    argv += ["--segmenter", "oracle", "--gt-labels", str(tmp_path / "gt.npy"), "--no-progress"]
    argv += ["--device", "cpu"] + ([flag] if flag else [])
    assert main(argv) == 0
    m = load_scene(out)
    kept, red, blue = m.density > 0, _inside(m, RED_BOX), _inside(m, BLUE_BOX)
    assert kept.any() and (kept & red).sum() > 0.95 * kept.sum()  # the red box
    assert (kept & blue & ~red).sum() <= 0.01 * kept.sum()  # not the blue one


def test_both_flags_are_one_clear_error(snapshot, tmp_path, capsys):
    from divas_engine.cli import main

    argv = ["segment", str(snapshot), "--prompts", str(tmp_path / "p.json")]
    argv += ["--out", str(tmp_path / "sel.ingp"), "--grid-views", "--network-views"]
    try:
        rc = main(argv)
    except SystemExit as e:  # the CLI's usage errors exit through argparse
        rc = e.code
    assert rc not in (0, None)
    err = capsys.readouterr().err
    assert "exclude each other" in err and "Traceback" not in err

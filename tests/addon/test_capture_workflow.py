"""A real capture through the whole add-on on the running Blender release: import (with its
display), a session with one click through a hand-placed anchor, accept, extract and
export. The add-on tier runs on every release CI covers (4.2 LTS to 5.2 LTS), so each
release does exactly this.

References: the engine's own pipeline (``divas segment`` on the same prompts, the same
process) for the labels and the exported file, the capture's rows for the extracted
points, and the hand-made ground truth of ``tests/data/targets/guitar`` for a floor under
the selection (one click on the guitar's body selects mostly guitar).
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge
from blender_addon.modal_logic import VIEW_PROP
from divas_engine import load_scene
from divas_engine.point_attributes import SELECTED

from .conftest import one_click_prompts

CAPTURE = "playcanvas-splats/guitar.compressed.ply"
SEED, SCALE = 0, 0.5


@pytest.fixture(scope="module")
def guitar(real_data, tmp_path_factory):
    """(capture, prompts file, ground-truth labels per scene row): the first hand-placed
    anchor of the guitar target and its first click."""
    path = tmp_path_factory.mktemp("guitar") / "prompts.json"
    truth = one_click_prompts(real_data, CAPTURE, "guitar", path)
    return real_data / CAPTURE, path, truth


def _ok(result) -> None:
    assert result == {"FINISHED"}, result


def test_capture_imports_segments_extracts_and_exports(guitar, tmp_path):
    from divas_engine.cli.segment import segment_scene
    from divas_engine.segment_request import SegmentRequest
    from divas_engine.session import load_prompts

    capture, prompts_path, truth = guitar
    ref = tmp_path / "engine"
    ref.mkdir()
    segment_scene(
        SegmentRequest(
            capture,
            prompts_path,
            out=ref / "sel.ply",
            labels_out=ref / "labels.npy",
            segmenter="graph3d",
            device="cpu",
            seed=SEED,
            scale=SCALE,
        ),
        progress=False,
    )
    ref_labels = np.load(ref / "labels.npy")  # per file row

    # import, with the default display (the first look)
    _ok(bpy.ops.divas.import_splats(filepath=str(capture)))
    obj = bpy.context.active_object
    assert obj.type == "POINTCLOUD" and bridge.point_count(obj.data) == len(load_scene(capture))

    # a session: one click through the anchor, accepted
    props = bpy.context.scene.divas
    props.render_scale, props.seed = SCALE, SEED
    _ok(bpy.ops.divas.start_session(segmenter="graph3d", device="cpu", prompts=str(prompts_path)))
    (click,) = load_prompts(prompts_path).anchors[0].clicks
    xy = f"{click.xy[0]!r} {click.xy[1]!r}"
    _ok(
        bpy.ops.divas.session_click(
            anchor=0, xy=xy, positive=True, full_resolution=True, preview=False
        )
    )
    view = bpy.context.scene.camera.get(VIEW_PROP)
    _ok(bpy.ops.divas.session_accept(view=view, points="[]", full_resolution=True))
    _ok(bpy.ops.divas.session_sync())
    selected = bridge.read_attribute(obj.data, SELECTED)
    rows = bridge.read_attribute(obj.data, "divas_index")
    assert selected.any()
    np.testing.assert_array_equal(np.isin(rows, np.flatnonzero(ref_labels)), selected)
    inter = np.logical_and(selected, truth).sum()
    assert inter / selected.sum() > 0.8 and inter / truth.sum() > 0.3

    # export: the file the engine wrote for the same selection
    out = tmp_path / "blender"
    out.mkdir()
    _ok(bpy.ops.divas.export_selection(filepath=str(out / "sel.ply"), write_labels=True))
    assert (out / "sel.ply").read_bytes() == (ref / "sel.ply").read_bytes()
    np.testing.assert_array_equal(np.load(out / "sel_labels.npy"), ref_labels)

    # extract: a new object of exactly the selected points
    positions = bridge.read_attribute(obj.data, "position")
    _ok(bpy.ops.divas.extract_selection())
    part = bpy.context.active_object
    assert part is not obj and part.type == "POINTCLOUD"
    np.testing.assert_array_equal(bridge.read_attribute(part.data, "position"), positions[selected])
    np.testing.assert_array_equal(bridge.read_attribute(part.data, "divas_index"), rows[selected])

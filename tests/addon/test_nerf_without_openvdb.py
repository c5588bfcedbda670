"""A Blender without an OpenVDB Python module (the ``bpy`` 4.2 wheel has none): Import ›
NeRF still imports the grid, shown as points, with one warning line; the Segmented Volume
is unavailable with its reason; a ``.vdb`` input is one error line, never a traceback."""

from __future__ import annotations

import numpy as np
import pytest

from blender_addon import bridge, compat, nerf_volume
from divas_engine.io import openvdb_grid
from divas_engine.io.instant_ngp import write_ngp_document
from divas_engine.point_attributes import SELECTED
from divas_engine.synthetic.ngp_snapshot import snapshot_of_grid

bpy = pytest.importorskip("bpy")


@pytest.fixture
def no_openvdb(monkeypatch):
    """The engine's finder (which the add-on uses too) finds no module."""
    monkeypatch.setattr(openvdb_grid, "openvdb_module", lambda: None)


@pytest.fixture(scope="module")
def ribs_ingp(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_novdb")
    sc = generate_scene("ribs", out, size=4_000, seed=0, grid_resolution=24)
    path = out / "ribs.ingp"
    write_ngp_document(path, snapshot_of_grid(sc.grid, sc.cameras[:2], network=False), True)
    return path


def test_the_add_on_and_the_engine_share_one_finder():
    assert compat.openvdb() is openvdb_grid.openvdb_module()
    assert nerf_volume.volumes_available() == (openvdb_grid.openvdb_module() is not None)


def test_import_falls_back_to_points_with_one_warning(no_openvdb, ribs_ingp, capfd):
    assert not nerf_volume.volumes_available()
    assert bpy.ops.divas.import_density_grid(filepath=str(ribs_ingp)) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.type == "POINTCLOUD" and len(obj.data.points) > 0
    assert nerf_volume.display_volume_of(obj) is None
    assert not any(o.type == "VOLUME" for o in bpy.data.objects)
    # the points display instead of the volume: drawn and rendered
    assert len(obj.modifiers) == 1 and obj.display_type != "BOUNDS" and not obj.hide_render
    out = capfd.readouterr()
    text = out.out + out.err
    assert "Traceback" not in text
    lines = [ln for ln in text.splitlines() if nerf_volume.NO_VOLUMES in ln]
    assert len(lines) == 1 and "shown as points" in lines[0]


def test_segmented_volume_says_why_it_is_unavailable(no_openvdb, ribs_ingp):
    assert bpy.ops.divas.import_density_grid(filepath=str(ribs_ingp)) == {"FINISHED"}
    obj = bpy.context.active_object
    bridge.write_attribute(obj.data, SELECTED, np.ones(len(obj.data.points), bool))
    assert not bpy.ops.divas.segmented_volume.poll()
    with pytest.raises(RuntimeError, match="no OpenVDB module"):
        bpy.ops.divas.segmented_volume()


def test_a_vdb_input_is_one_error_line(no_openvdb, tmp_path, capfd):
    path = tmp_path / "smoke.vdb"
    path.write_bytes(b"\x20BDV" + bytes(60))
    with pytest.raises(RuntimeError) as err:
        bpy.ops.divas.import_density_grid(filepath=str(path))
    msg = str(err.value).strip()
    assert "smoke.vdb" in msg and "OpenVDB" in msg and "\n" not in msg
    assert "Traceback" not in capfd.readouterr().err

"""PlayCanvas streamed LOD (``lod-meta.json``) read one level at a time, and written back.

The scene is ``tests/data/splat-transform-lod/`` (made by splat-transform 3.10.2 from the
GaussianSplats3D tiles, ``tests/data/README.md``): two levels, level 0 in three SOG
units. The references are splat-transform's own: ``splat-transform-info.json`` (its
``--info json``: per-level counts) and ``reference.npz`` (its decode of each level,
``-L <level>`` to PLY, read with ``plyfile``), so nothing here is checked against this
repository's code alone.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from divas_engine.cli import main
from divas_engine.errors import DivasInputError
from divas_engine.export import export_selection
from divas_engine.io.load import detect_format, load_scene

LOD = Path(__file__).resolve().parent / "data" / "splat-transform-lod"
META = LOD / "lod-meta.json"


@pytest.fixture(scope="module")
def info() -> dict:
    return json.loads((LOD / "splat-transform-info.json").read_text())


@pytest.fixture(scope="module")
def reference() -> dict:
    with np.load(LOD / "reference.npz") as z:
        return {k: z[k] for k in z.files}


def test_format_is_found_from_the_name_and_the_folder():
    assert detect_format(META) == "lod"
    assert detect_format(LOD) == "lod"


@pytest.mark.parametrize("level", [0, 1])
def test_each_level_has_splat_transforms_count_and_rows(level, info, reference):
    sc = load_scene(META, lod=level)
    assert info["numLods"] == 2 and sc.extras["lod_levels"] == 2
    assert len(sc) == sc.source.num_rows == info["lodCounts"][level]
    assert sc.extras["lod_counts"] == info["lodCounts"]
    assert sc.source.format == "lod" and sc.extras["lod_level"] == level
    # splat-transform's rows of this level, in its order (units by file index)
    xyz = reference[f"xyz_{level}"][sc.source.kept_rows]
    np.testing.assert_allclose(sc.means, xyz, rtol=1e-6, atol=1e-6)
    op = 1.0 / (
        1.0 + np.exp(-reference[f"opacity_{level}"][sc.source.kept_rows].astype(np.float64))
    )
    np.testing.assert_allclose(sc.opacities, op, atol=2e-6)


def test_default_level_is_the_finest_and_negative_counts_from_the_coarsest(info):
    assert len(load_scene(META)) == info["lodCounts"][0]
    assert len(load_scene(META, lod=-1)) == info["lodCounts"][1]


def test_level_zero_is_its_units_concatenated_in_file_order():
    sc = load_scene(META, lod=0)
    units = sc.extras["lod_units"]
    assert [u[0] for u in units] == ["0_0/meta.json", "0_1/meta.json", "0_2/meta.json"]
    start = 0
    for name, count in units:
        part = load_scene(LOD / name)
        assert len(part) == count
        np.testing.assert_array_equal(sc.means[start : start + count], part.means)
        start += count
    assert start == len(sc)


def test_info_names_the_levels_and_refuses_a_missing_level(capsys):
    assert main(["info", str(META), "--lod", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["format"] == "lod" and out["count"] == 1971 and out["lod_counts"] == [6831, 1971]
    assert main(["info", str(META), "--lod", "2"]) == 2
    err = capsys.readouterr().err
    assert "no level 2" in err and "levels 0..1" in err and "SOG" not in err
    sog = LOD.parent / "playcanvas-sog" / "playbot_lod3"
    assert main(["info", str(sog), "--lod", "0"]) == 2
    assert "--lod applies to lod-meta.json" in capsys.readouterr().err


def _copy(tmp_path: Path) -> Path:
    d = tmp_path / "lod"
    shutil.copytree(LOD, d)
    return d


def _edit(d: Path, fn) -> Path:
    doc = json.loads((d / "lod-meta.json").read_text())
    fn(doc)
    (d / "lod-meta.json").write_text(json.dumps(doc))
    return d / "lod-meta.json"


def _first_leaf(node: dict) -> dict:
    while "children" in node:
        node = node["children"][0]
    return node


@pytest.mark.parametrize(
    "edit, says",
    [
        (lambda d: d.update(version=2), "unsupported lod-meta.json version 2"),
        (lambda d: d.update(lodLevels=0), "'lodLevels' must be a positive integer"),
        (lambda d: d.update(counts=[6831, 1970]), "level 1: 'counts' gives 1970, the tree 1971"),
        (lambda d: d["filenames"].__setitem__(0, "../x/meta.json"), "leaves the scene's folder"),
        (lambda d: d.update(tree=[]), "'tree' must be an object"),
        (
            lambda d: _first_leaf(d["tree"])["lods"].__setitem__("7", {"file": 0}),
            "tree: bad reference '7'",
        ),
        (
            lambda d: _first_leaf(d["tree"])["lods"]["0"].update(file=0),
            "holds levels",
        ),
    ],
)
def test_bad_manifests_are_one_clear_error(tmp_path, edit, says):
    meta = _edit(_copy(tmp_path), edit)
    with pytest.raises(DivasInputError, match="lod-meta.json") as e:
        load_scene(meta)
    assert says in str(e.value)


def test_a_unit_that_disagrees_with_the_tree_is_named(tmp_path):
    d = _copy(tmp_path)
    shutil.rmtree(d / "1_0")
    shutil.copytree(LOD / "0_0", d / "1_0")  # a unit of another size in its place
    with pytest.raises(DivasInputError, match=r"1_0.*lod-meta.json gives 1971 for level 1"):
        load_scene(d / "lod-meta.json", lod=1)
    assert len(load_scene(d / "lod-meta.json", lod=0)) == 6831  # the other level still loads
    shutil.rmtree(d / "0_1")
    with pytest.raises(DivasInputError, match="0_1"):
        load_scene(d / "lod-meta.json", lod=0)


@pytest.mark.parametrize("level", [0, 1])
def test_export_writes_a_one_level_lod_scene_of_the_selection(tmp_path, level):
    sc = load_scene(META, lod=level)
    sel = sc.means[:, 0] > np.median(sc.means[:, 0])
    res = export_selection(sc, sel, tmp_path / "sel", labels_path=tmp_path / "labels.npy")
    assert res.format == "lod" and res.path == tmp_path / "sel" / "lod-meta.json"
    doc = json.loads(res.path.read_text())
    assert doc["lodLevels"] == 1 and doc["counts"] == [int(sel.sum())]
    back = load_scene(res.path)
    # the kept Gaussians decode bit-identically, in the source's order
    np.testing.assert_array_equal(back.means, sc.means[sel])
    np.testing.assert_array_equal(back.quats, sc.quats[sel])
    np.testing.assert_array_equal(back.sh, sc.sh[sel])
    np.testing.assert_array_equal(np.load(tmp_path / "labels.npy"), sel)
    # every tree reference points at the kept rows of its leaf: leaves partition the units
    refs = []
    stack = [doc["tree"]]
    while stack:
        n = stack.pop()
        stack.extend(n.get("children", []))
        refs += list(n.get("lods", {}).values())
    for f, name in enumerate(doc["filenames"]):
        mine = sorted((r["offset"], r["count"]) for r in refs if r["file"] == f)
        ends = [o + c for o, c in mine]
        assert [o for o, _ in mine] == [0] + ends[:-1]
        assert ends[-1] == len(load_scene(res.path.parent / name))


def test_export_refuses_the_input_and_foreign_folders_and_replaces_its_own(tmp_path):
    d = _copy(tmp_path)
    sc = load_scene(d / "lod-meta.json", lod=1)
    sel = np.zeros(len(sc), bool)
    sel[:100] = True
    with pytest.raises(DivasInputError, match="overwrite the input"):
        export_selection(sc, sel, d)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    with pytest.raises(DivasInputError, match="more than a LOD scene"):
        export_selection(sc, sel, other)
    assert (other / "notes.txt").read_text() == "keep me"
    with pytest.raises(DivasInputError, match="exports as a folder"):
        export_selection(sc, sel, tmp_path / "sel.ply")
    out = export_selection(sc, sel, tmp_path / "sel").path
    sel[:200] = True
    again = export_selection(sc, sel, out).path  # its own earlier export: replaced
    assert len(load_scene(again)) == 200

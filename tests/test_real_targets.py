"""Ground truth made by rule on the shared real captures: the committed label
files are their rules applied to the committed captures, with the recorded counts and
SHA-256; the oracle anchors' clicks land on their targets; the test views are above the
ground and show the target.

Captures: tests/data (playcanvas/engine @ 0aaef5e, MIT; mkkellogg/GaussianSplats3D
PR 477, MIT — tests/data/README.md). Rules: divas_engine/evaluation/real_target_defs.py,
each checked by eye on renders (the ``check`` note in targets.json says what was seen).
"""

from __future__ import annotations

import hashlib
import itertools
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from divas_engine.evaluation.real_target_defs import CAPTURES
from divas_engine.evaluation.real_targets import (
    capture_layout,
    evaluation_cameras,
    oracle_anchors,
    read_targets,
    rule_labels,
    sha256_file,
    target_scene_labels,
)
from divas_engine.evaluation.target_rules import GaussianFeatures, evaluate_rule
from divas_engine.io.load import load_scene
from divas_engine.render import make_renderer
from tests.framing_checks import angle_deg, rendered_framing

DATA = Path(__file__).parent / "data"
TARGETS = DATA / "targets"

#: SHA-256 of the committed label files (packed bits per file row)
LABEL_SHA256 = {
    "biker/head.npy": "882ca03cb99d07bb83f9c565477a55152b334cea25de2104b530635680523620",
    "biker/helmet.npy": "7a05db2a47445e7632336c09dfcc7c2ef78329f779acaf0f36b7e1655f7ec955",
    "biker_spz/helmet.npy": "005255591172445a4ef02a6fbff7ba9965495dc10553ff1a2d97d0fb938e553e",
    "guitar/guitar.npy": "35e37a8780f0d02eb6f01520197da711b3a97a062d80cdb0b0fb26a024351c25",
    "guitar/neck.npy": "f51c0e2f5796ab1858b043fac8fa6c3c145b02bd48d1a443ff46158b75db0d3c",
    "guitar/stand.npy": "2e296e97005278a2e04253aa3ff7b18f07a24345b8e4c55cc28d129cd7f3f9df",
    "lod1/plants.npy": "b365f5d1c7875a9bd2bebe0074861210887df43016ab333712443dc048b7b53f",
}
#: selected Gaussians per target (of 152746 / 152746 / 90854 / 14051 rows)
COUNTS = {
    "biker/head": 10497,
    "biker/helmet": 14723,
    "biker_spz/helmet": 14729,
    "guitar/guitar": 80403,
    "guitar/neck": 22539,
    "guitar/stand": 8607,
    "lod1/plants": 12584,
}
WITH_TARGETS = [n for n, c in CAPTURES.items() if c.targets]


@cache
def _scene(name: str):
    return load_scene(DATA / CAPTURES[name].path)


@cache
def _doc(name: str) -> dict:
    return read_targets(TARGETS / name)


def test_committed_label_files_have_the_recorded_sha256():
    found = {
        str(p.relative_to(TARGETS)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(TARGETS.glob("*/*.npy"))
    }
    assert found == LABEL_SHA256
    for key, sha in LABEL_SHA256.items():
        cap, file = key.split("/")
        assert _doc(cap)["targets"][Path(file).stem]["sha256"] == sha


def test_every_capture_has_a_targets_file_with_its_true_up():
    for name, cap in CAPTURES.items():
        doc = _doc(name)
        assert doc["capture"] == cap.path
        assert doc["capture_sha256"] == sha256_file(DATA / cap.path)
        assert doc["true_up"] == list(cap.true_up) and doc["true_up_note"] == cap.up_note
        assert set(doc["targets"]) == {t.name for t in cap.targets}
    kinds = [t["kind"] for c in WITH_TARGETS for t in _doc(c)["targets"].values()]
    assert kinds.count("object on a support") >= 1 and kinds.count("part of an object") >= 1
    assert sum(len(_doc(c)["targets"]) for c in WITH_TARGETS) >= 5


def _on_a_boundary(scene, rule: dict) -> np.ndarray:
    """``[num_rows]`` bool: rows whose label changes when a rule input (centre, opacity,
    base colour: float32) moves by one float32 ulp, in any of the directions below."""
    m = scene.means.astype(np.float32)
    o = scene.opacities.astype(np.float32)
    rgb = scene.base_colors().astype(np.float32)

    def nudge(x: np.ndarray, signs) -> np.ndarray:
        s = np.asarray(signs, np.float32)
        return np.where(s == 0, x, np.nextafter(x, x + s))

    base = evaluate_rule(rule, GaussianFeatures(m, o, rgb))
    variants = [(nudge(m, s), o, rgb) for s in itertools.product((-1, 1), repeat=3)]
    variants += [(m, nudge(o, s), rgb) for s in (-1, 1)]
    variants += [(m, o, nudge(rgb, s)) for s in itertools.product((-1, 0, 1), repeat=3) if any(s)]
    moved = np.zeros(len(base), bool)
    for v in variants:
        moved |= evaluate_rule(rule, GaussianFeatures(*v)) != base
    out = np.zeros(scene.source.num_rows, bool)
    out[scene.source.kept_rows] = moved
    return out


@pytest.mark.parametrize("capture", WITH_TARGETS)
def test_label_files_are_their_rules(capture):
    """The committed files were written on another CPU: the rules' float64 products
    (``@``: the BLAS kernels the CPU picks) may differ in their last bits, far below one
    float32 ulp of the inputs. A row may then disagree with its file only where one ulp
    of its inputs moves it across the rule's boundary (none do on the CPUs tried)."""
    scene, doc = _scene(capture), _doc(capture)
    assert doc["rows"] == scene.source.num_rows
    defs = {t.name: t for t in CAPTURES[capture].targets}
    for name, t in doc["targets"].items():
        assert t["rule"] == defs[name].rule  # the file records the rule in the code
        regenerated = rule_labels(scene, t["rule"])
        differ = np.flatnonzero(regenerated != t["labels"])
        if len(differ):
            edge = _on_a_boundary(scene, t["rule"])
            assert edge[differ].all(), (name, differ[~edge[differ]][:10])
        assert t["count"] == int(t["labels"].sum()) == COUNTS[f"{capture}/{name}"]


def test_boundary_rows_are_found():
    """:func:`_on_a_boundary` finds a row put exactly on a rule's boundary, and only it."""
    scene = _scene("lod1")
    i = 123
    x = float(scene.means[i, 0])
    rule = {"halfspace": {"normal": [1.0, 0.0, 0.0], "offset": x}}
    edge = _on_a_boundary(scene, rule)
    assert edge[scene.source.kept_rows[i]]
    on_plane = scene.means[:, 0].astype(np.float32) == np.float32(x)
    assert edge.sum() == on_plane.sum()


def test_relations_between_targets():
    g = _doc("guitar")["targets"]
    guitar, neck, stand = g["guitar"]["labels"], g["neck"]["labels"], g["stand"]["labels"]
    assert not (guitar & stand).any()  # the guitar rests on the stand; no Gaussian is both
    assert (neck & ~guitar).sum() == 0 and 0.2 < neck.sum() / guitar.sum() < 0.4  # a part
    b = _doc("biker")["targets"]
    assert not (b["helmet"]["labels"] & b["head"]["labels"]).any()
    # the same rule on the same scene in another format selects ~the same Gaussians
    n1, n2 = b["helmet"]["count"], _doc("biker_spz")["targets"]["helmet"]["count"]
    assert abs(n1 - n2) / n1 < 0.005
    # the plants stand on the ground layer: what is left is the thin ground
    lod = _scene("lod1")
    rest = ~_doc("lod1")["targets"]["plants"]["labels"]
    z = lod.means[rest[lod.source.kept_rows], 2]
    assert np.percentile(z, 95) < 0.75 and np.percentile(z, 5) > 0.55


@pytest.mark.parametrize("capture", WITH_TARGETS)
def test_oracle_clicks_land_on_their_targets(capture):
    scene, doc = _scene(capture), _doc(capture)
    ren = make_renderer(scene, device="cpu")
    for name, t in doc["targets"].items():
        lab = target_scene_labels(scene, doc, name).astype(np.float32)
        anchors = oracle_anchors(scene, CAPTURES[capture].true_up, t["anchors"])
        assert anchors, name
        for cam, _, _, clicks in anchors:
            cov = ren.render_values(cam, lab, 0.5)
            alpha = ren.render(cam, 0.5).alpha
            for x, y in clicks:
                i, j = int(y * 0.5), int(x * 0.5)
                assert alpha[i, j] > 0.5 and cov[i, j] > 0.5, (name, cam.name, (x, y))


@pytest.mark.parametrize("target", ["guitar/neck", "biker/helmet", "lod1/plants"])
def test_evaluation_views_are_above_the_ground_and_show_the_target(target):
    capture, name = target.split("/")
    scene, doc, up = _scene(capture), _doc(capture), np.array(CAPTURES[capture].true_up)
    lab = target_scene_labels(scene, doc, name)
    cams = evaluation_cameras(scene, lab, up, device="cpu")
    assert len(cams) >= 8
    whole = capture_layout(scene, up)
    ren = make_renderer(scene, device="cpu")
    for cam in cams:
        if whole.floor is not None:
            assert whole.height(cam.center) > 0
        assert abs(cam.right @ up) < 1e-9 and angle_deg(cam.up, up) < 90.0
        fr = rendered_framing(ren.render_values(cam, lab.astype(np.float32), 0.25))
        assert fr.fill_larger_side > 0.4  # the target is in sight and framed, not a speck

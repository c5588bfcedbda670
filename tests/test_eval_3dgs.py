"""``divas eval --kind 3dgs``: the suite on the trained-3DGS variants — the
completion's row, the paper's selection before it, both peers and the truth as the
metrics' ceiling, on one CI-sized scene."""

from __future__ import annotations

import argparse

import pytest

from divas_engine.evaluation.metrics import EvalConfig
from divas_engine.kinds import SceneKind

CPU = "cpu"


def test_eval_3dgs_rows_end_to_end():
    from divas_engine.evaluation.suite import SuiteConfig, evaluate_scene, markdown_table
    from divas_engine.session import SessionConfig

    cfg = SuiteConfig(
        scenes=("occluded",),
        segmenters=("oracle",),
        size=8_000,
        nerf=False,
        kind="3dgs",
        ablations=False,
        fidelity=True,
        session=SessionConfig(render_scale=0.5),
        eval=EvalConfig(scale=0.5),
    )
    rows = evaluate_scene("occluded", cfg, device=CPU)
    by = {r["method"]: r for r in rows}
    assert list(by) == [
        "full",
        "pass1",
        "pass12",
        "centre_vote",
        "contrib_vote",
        "no_completion",
        "truth",
    ]
    assert all(r["kind"] == SceneKind.GS3D for r in rows)
    # the truth scores 1 on every per-Gaussian metric; its image IoU is the ceiling
    t = by["truth"]
    assert t["opacity_weighted_iou"] == 1.0 and t["alpha_fidelity"] == pytest.approx(1.0)
    assert t["precision_3d"] == t["recall_3d"] == 1.0
    # the completion adds what the paper's passes miss on a 3DGS scene
    assert by["full"]["recall_3d"] > by["no_completion"]["recall_3d"]
    assert by["full"]["alpha_fidelity"] > by["no_completion"]["alpha_fidelity"]
    text = markdown_table({"rows": rows})
    assert "ground truth itself" in text and "w/o 3DGS completion" in text


def test_eval_cli_kind_and_ablations():
    from divas_engine.cli import evaluate
    from divas_engine.evaluation.suite import SuiteConfig

    p = argparse.ArgumentParser()
    evaluate.add_parser(p.add_subparsers())
    a = p.parse_args(["eval", "--kind", "3dgs", "--no-ablations"])
    assert a.kind == "3dgs" and a.no_ablations
    d = p.parse_args(["eval"])
    assert d.kind == "2dgs" and not d.no_ablations
    with pytest.raises(SystemExit):
        p.parse_args(["eval", "--kind", "nerf"])
    assert SuiteConfig(kind="3dgs").kind == SceneKind.GS3D
    with pytest.raises(ValueError):
        SuiteConfig(kind="nerf")

"""The evaluation table on the synthetic suite (``divas eval``).

Per scene (generated in memory, :func:`~divas_engine.synthetic.generate_scene`) and per
segmenter (SAM-like oracle, classic): the scripted sessions of
:mod:`.pipeline` (view protocol ``"user"``: the simulated user of :mod:`.scripted_user`
on the session's anchor plan, default; ``"clicks"``: the metadata clicks) — DivAS full,
without the thin path, without depth weighting — then
Pass 1 only / Pass 1+2 from the full session's mapping chain, and the peer baselines
(:mod:`.baselines`) fed the full session's accepted view masks (the raw masks the
segmenter returned, before DivAS's depth weighting: what the user accepted;
``baseline_masks="weighted"`` feeds the depth-weighted ones instead). Every selection is
scored at the scene's held-out test cameras (:class:`.metrics.ViewEvaluator`: mean IoU
and pixel accuracy over the views) and per primitive (precision / recall).

The NeRF path runs on the ribs density grid (``ribs`` only): DivAS full (and without
depth weighting), scored with the segmented-density renders, per-voxel precision/recall
against the label grid.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..kinds import SceneKind, ViewStatus
from ..session import SessionConfig
from .baselines import CentreVoteConfig, ContributionVoteConfig, ContributionVoter, centre_vote
from .metrics import EvalConfig, ViewEvaluator
from .pipeline import CachingRenderer, make_segmenter, run_session, scripted_anchors, variant_config
from .scripted_user import ScriptedUser, UserBudget
from .suite_table import markdown_table

__all__ = [
    "METHODS",
    "NERF_METHODS",
    "PROTOCOLS",
    "SuiteConfig",
    "evaluate_scene",
    "evaluate_suite",
    "markdown_table",
    "check_targets",
]

#: Table rows per (scene, segmenter) on surfels, in order: key → label.
METHODS: dict[str, str] = {
    "full": "DivAS full",
    "no_thin": "w/o thin path",
    "no_depth_weight": "w/o depth weighting",
    "pass1": "Pass 1 only",
    "pass12": "Pass 1+2",
    "centre_vote": "(a) centre-projection vote",
    "contrib_vote": "(b) contribution vote (FlashSplat-style)",
}
#: Extra rows on 3DGS-derived scenes (``SceneKind.GS3D``): the paper's selection before
#: the completion of volumetric scenes (beyond the paper).
GS3D_METHODS: dict[str, str] = {
    "no_completion": "w/o 3DGS completion (paper passes)",
    "truth": "the ground truth itself (the metrics' ceiling)",
}
#: View protocols: ``"user"`` — the simulated user on the session's anchor plan
#: (:mod:`.scripted_user`, the paper's); ``"clicks"`` — the metadata clicks on training
#: cameras (the ``divas demo`` protocol).
PROTOCOLS: tuple[str, ...] = ("user", "clicks")

#: Rows of the NeRF path.
NERF_METHODS: dict[str, str] = {
    "nerf_full": "DivAS NeRF full",
    "nerf_no_depth_weight": "DivAS NeRF w/o depth weighting",
}


@dataclass(frozen=True)
class SuiteConfig:
    """What ``divas eval`` runs.

    Attributes:
        scenes: synthetic scene names.
        segmenters: ``"oracle"`` and/or ``"classic"``.
        size: surfels per scene; seed: scene, oracle and classic seed.
        seeds: run the whole suite once per seed (overrides ``seed``; empty = ``seed``
            only). One synthetic instance is a noisy estimate — on plant the DivAS and
            centre-vote IoUs move by ±0.03 between seeds — so the targets are checked on
            the per-scene means over the seeds, and the per-seed wins are listed.
        nerf: run the NeRF path on the ribs grid.
        grid_resolution: cells along the longest side of the ribs grid.
        baseline_masks: ``"raw"`` (segmenter output) or ``"weighted"`` (what DivAS fused).
        protocol: :data:`PROTOCOLS` (``"user"``). With ``"user"`` every variant session
            is driven by the same simulated user policy reacting to that variant's own
            overlay (so ablations may click differently); the baselines get the full
            session's accepted masks.
        user: the simulated user's budgets.
        eval: thresholds / test-camera scale.
        session: the base session config (variants change one field of it).
        centre_vote, contrib_vote: baseline constants.
        fidelity: also score alpha fidelity, opacity-weighted IoU and the
            extracted-object PSNR (:mod:`.fidelity`; one render of each selection alone
            per test camera).
        kind: ``"2dgs"`` (the paper's surfels, default) or ``"3dgs"`` (the trained-3DGS
            variants of the same scenes, ``divas generate --kind 3dgs``; the NeRF path
            does not run, the "w/o 3DGS completion" row is added).
        ablations: also run the ``no_thin`` / ``no_depth_weight`` variant sessions
            (False: DivAS full, the pass rows and the peers only).
    """

    scenes: tuple[str, ...] = ("ribs", "plant", "occluded")
    segmenters: tuple[str, ...] = ("oracle", "classic")
    size: int = 20_000
    seed: int = 0
    seeds: tuple[int, ...] = ()
    nerf: bool = True
    grid_resolution: int = 128
    baseline_masks: str = "raw"
    protocol: str = "user"
    user: UserBudget = field(default_factory=UserBudget)
    eval: EvalConfig = field(default_factory=EvalConfig)
    session: SessionConfig = field(default_factory=SessionConfig)
    centre_vote: CentreVoteConfig = field(default_factory=CentreVoteConfig)
    contrib_vote: ContributionVoteConfig = field(default_factory=ContributionVoteConfig)
    fidelity: bool = False
    kind: SceneKind = SceneKind.GS2D
    ablations: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", SceneKind(self.kind))
        if self.kind not in (SceneKind.GS2D, SceneKind.GS3D):
            raise ValueError(f"kind must be 2dgs or 3dgs, got {self.kind!r}")
        if self.baseline_masks not in ("raw", "weighted"):
            raise ValueError(
                f"baseline_masks must be 'raw' or 'weighted', got {self.baseline_masks!r}"
            )
        if self.protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {PROTOCOLS}, got {self.protocol!r}")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct, got {self.seeds}")

    @property
    def run_seeds(self) -> tuple[int, ...]:
        """The seeds the suite runs: ``seeds``, or ``(seed,)``."""
        return tuple(self.seeds) or (self.seed,)


def _row(
    scene: str,
    kind: str,
    seg: str,
    method: str,
    label: str,
    sc,
    extra: dict,
    seed: int,
    fid: dict | None = None,
) -> dict:
    p = sc.primitives or {}
    return {
        "scene": scene,
        "seed": seed,
        "kind": kind,
        "segmenter": seg,
        "method": method,
        "label": label,
        "iou": sc.iou,
        "accuracy": sc.accuracy,
        "pooled_iou": sc.pooled_iou,
        "precision_2d": sc.precision,
        "recall_2d": sc.recall,
        "precision_3d": p.get("precision"),
        "recall_3d": p.get("recall"),
        "iou_3d": p.get("iou"),
        "selected": p.get("selected"),
        "per_view_iou": [v.iou for v in sc.views],
        **(fid or {}),
        **extra,
    }


def evaluate_scene(
    name: str,
    config: SuiteConfig = SuiteConfig(),
    *,
    device=None,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """All rows of one synthetic scene (surfel methods × segmenters, + NeRF for ribs)."""
    from ..render import make_renderer
    from ..synthetic import generate_scene

    say = log or (lambda _m: None)
    t0 = time.perf_counter()
    sc = generate_scene(
        name,
        size=config.size,
        seed=config.seed,
        grid_resolution=config.grid_resolution,
        kind=config.kind,
    )
    anchors = scripted_anchors(sc.metadata, sc.cameras) if config.protocol == "clicks" else None
    renderer = make_renderer(sc.scene, device=device, config=config.session.render)
    cached = CachingRenderer(renderer)  # the variant sessions share anchor/view renders
    say(
        f"{name}: {len(sc.scene)} surfels, protocol {config.protocol}"
        + (
            ""
            if anchors is None
            else f", {len(anchors)} anchors, {sum(len(a[3]) for a in anchors)} clicks"
        )
        + f", {len(sc.test_cameras)} test cameras ({time.perf_counter() - t0:.1f} s)"
    )
    selections: dict[str, np.ndarray] = {}
    extras: dict[str, dict] = {}
    voter = ContributionVoter(sc.scene, device, config.session.render)
    for seg in config.segmenters:
        full = None
        for var in ("full", "no_thin", "no_depth_weight") if config.ablations else ("full",):
            out = run_session(
                sc.scene,
                sc.cameras,
                sc.labels,
                anchors,
                segmenter=make_segmenter(seg, config.seed),
                config=variant_config(var, config.session),
                device=device,
                renderer=cached,
                user=_user(config, sc.labels),
            )
            fused = sum(1 for _, st, _ in out.statuses if st == ViewStatus.FUSED)
            selections[f"{seg}/{var}"] = out.selection
            extras[f"{seg}/{var}"] = {
                "views_fused": fused,
                "views": len(out.statuses),
                "seconds": out.seconds,
                **_user_extra(out),
            }
            say(
                f"  {seg:7s} {var:16s} {fused}/{len(out.statuses)} views fused, "
                f"{int(out.selection.sum())} selected ({out.seconds:.1f} s)" + _user_note(out)
            )
            if var == "full":
                full = out
        assert full is not None
        ex = {
            "views_fused": extras[f"{seg}/full"]["views_fused"],
            "views": extras[f"{seg}/full"]["views"],
        }
        if full.completion is not None:  # 3DGS: the paper's selection before completion
            selections[f"{seg}/no_completion"] = full.mapped
            extras[f"{seg}/no_completion"] = dict(ex)
            extras[f"{seg}/full"]["completion"] = full.completion
            # the truth scored as a selection: the metrics' ceiling, reported alongside
            # (its image IoU is 1 with the 3DGS thresholds; fidelity and PSNR are not)
            selections[f"{seg}/truth"] = np.asarray(sc.labels, bool)
            extras[f"{seg}/truth"] = dict(ex)
        selections[f"{seg}/pass1"], extras[f"{seg}/pass1"] = full.pass1, dict(ex)
        selections[f"{seg}/pass12"], extras[f"{seg}/pass12"] = full.pass2, dict(ex)
        mviews = full.views if config.baseline_masks == "raw" else full.weighted_views
        a = centre_vote(sc.scene, mviews, config=config.centre_vote, renderer=renderer)
        b = voter.vote(mviews, config.contrib_vote)
        selections[f"{seg}/centre_vote"] = a.selected
        extras[f"{seg}/centre_vote"] = {**ex, "seconds": a.seconds}
        selections[f"{seg}/contrib_vote"] = b.selected
        extras[f"{seg}/contrib_vote"] = {**ex, "seconds": b.seconds}
        say(
            f"  {seg:7s} baselines: centre vote {int(a.selected.sum())}, contribution vote "
            f"{int(b.selected.sum())} selected ({a.seconds + b.seconds:.1f} s)"
        )
    t = time.perf_counter()
    ev = ViewEvaluator(
        sc.scene, sc.test_cameras, sc.labels, config=config.eval, renderer=renderer, device=device
    )
    scores = ev.score(selections)
    fids: dict[str, dict] = {}
    if config.fidelity:
        from .fidelity import FidelityEvaluator

        fids = FidelityEvaluator(
            sc.scene,
            sc.test_cameras,
            sc.labels,
            gt_masks=ev.gt_masks,
            scale=config.eval.scale,
            renderer=renderer,
            device=device,
        ).score(selections)
    say(
        f"  scored {len(selections)} selections at {len(sc.test_cameras)} test cameras "
        f"({time.perf_counter() - t:.1f} s)"
    )
    rows = []
    kind = SceneKind(sc.scene.kind)
    for seg in config.segmenters:
        for m, label in {**METHODS, **GS3D_METHODS}.items():
            k = f"{seg}/{m}"
            if k not in selections:
                continue
            rows.append(
                _row(name, kind, seg, m, label, scores[k], extras[k], config.seed, fids.get(k))
            )
    if config.nerf and sc.grid is not None:
        rows += _nerf_rows(name, sc, anchors, config, device, say)
    return rows


def _user(config: SuiteConfig, labels: np.ndarray) -> ScriptedUser | None:
    return ScriptedUser(labels, config.user) if config.protocol == "user" else None


def _user_extra(out) -> dict:
    if out.user_log is None:
        return {}
    d = out.user_log.as_dict()
    return {
        "user": {
            "stop": d["stop"],
            "anchor_status": d["anchor_status"],
            "uncovered_after": d["uncovered_after"],
            "negatives": d["negatives"],
            "negatives_kept": d["negatives_kept"],
            "declined": d["declined"],
            "manual_anchors": d["manual_anchors"],
            "clicks": [
                (
                    c["anchor"],
                    round(c["xy"][0], 1),
                    round(c["xy"][1], 1),
                    c["region_px"],
                    c["status"],
                )
                for c in d["clicks"]
            ],
            "anchors": out.anchors,
        }
    }


def _user_note(out) -> str:
    if out.user_log is None:
        return ""
    lg = out.user_log
    st = lg.anchor_status
    return (
        f"; user: {len(lg.clicks)} clicks"
        + (f" ({lg.declined} declined)" if lg.declined else "")
        + f", stop {lg.stop}, anchors complete "
        f"{st.count('complete')}/{len(st) - st.count('not visited')} visited "
        f"of {len(st)}" + (f", manual anchors {lg.manual}" if lg.manual else "")
    )


def _nerf_rows(name, sc, anchors, config: SuiteConfig, device, say) -> list[dict]:
    from ..render import make_renderer

    grid, labels = sc.grid, sc.grid_labels
    renderer = CachingRenderer(make_renderer(grid, device=device, config=config.session.render))
    sels, extras = {}, {}
    for seg in config.segmenters:
        for var, key in (("full", "nerf_full"), ("no_depth_weight", "nerf_no_depth_weight")):
            out = run_session(
                grid,
                sc.cameras,
                labels,
                anchors,
                segmenter=make_segmenter(seg, config.seed),
                config=variant_config(var, config.session),
                device=device,
                renderer=renderer,
                user=_user(config, labels),
            )
            fused = sum(1 for _, st, _ in out.statuses if st == ViewStatus.FUSED)
            sels[f"{seg}/{key}"] = out.selection
            extras[f"{seg}/{key}"] = {
                "views_fused": fused,
                "views": len(out.statuses),
                "seconds": out.seconds,
                **_user_extra(out),
            }
            say(
                f"  nerf {seg:7s} {var:16s} {fused}/{len(out.statuses)} views fused, "
                f"{int(out.selection.sum())} voxels ({out.seconds:.1f} s)" + _user_note(out)
            )
    t = time.perf_counter()
    ev = ViewEvaluator(grid, sc.test_cameras, labels, config=config.eval, device=device)
    scores = ev.score(sels)
    say(f"  nerf scored {len(sels)} selections ({time.perf_counter() - t:.1f} s)")
    return [
        _row(
            name,
            SceneKind.NERF,
            seg,
            m,
            label,
            scores[f"{seg}/{m}"],
            extras[f"{seg}/{m}"],
            config.seed,
        )
        for seg in config.segmenters
        for m, label in NERF_METHODS.items()
    ]


def evaluate_suite(
    config: SuiteConfig = SuiteConfig(), *, device=None, log: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Rows of every scene of ``config`` (per seed of :attr:`SuiteConfig.run_seeds`), the
    per-scene means over the seeds, per-method means over the scenes, and the targets."""
    t0 = time.perf_counter()
    rows: list[dict] = []
    for seed in config.run_seeds:
        cfg = replace(config, seed=seed, seeds=())
        if len(config.run_seeds) > 1 and log is not None:
            log(f"seed {seed}:")
        for name in config.scenes:
            rows += evaluate_scene(name, cfg, device=device, log=log)
    per_scene = scene_means(rows)
    return {
        "version": 1,
        "config": {
            "scenes": list(config.scenes),
            "segmenters": list(config.segmenters),
            "size": config.size,
            "seed": config.seed,
            "seeds": list(config.run_seeds),
            "baseline_masks": config.baseline_masks,
            "protocol": config.protocol,
            "user": config.user.__dict__.copy() if config.protocol == "user" else None,
            "eval": config.eval.__dict__.copy(),
            "oracle_seed": config.seed,
        },
        "rows": rows,
        "scene_means": per_scene,
        "means": suite_means(per_scene),
        "targets": check_targets(rows),
        "seconds": time.perf_counter() - t0,
    }


_METRICS = (
    "iou",
    "accuracy",
    "precision_3d",
    "recall_3d",
    "alpha_fidelity",
    "opacity_weighted_iou",
    "psnr",
)


def _mean(rs: Sequence[dict], k: str) -> float | None:
    vals = [r[k] for r in rs if r.get(k) is not None]
    return float(np.mean(vals)) if vals else None


def scene_means(rows: Sequence[dict]) -> list[dict]:
    """Per (scene, kind, segmenter, method): the metrics averaged over the seeds, with the
    per-seed IoUs (``iou_seeds``) and their range."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["scene"], r["kind"], r["segmenter"], r["method"]), []).append(r)
    out = []
    for (scene, kind, seg, m), rs in groups.items():
        ious = [float(r["iou"]) for r in rs]
        out.append(
            {
                "scene": scene,
                "kind": kind,
                "segmenter": seg,
                "method": m,
                "label": rs[0]["label"],
                "seeds": [r.get("seed") for r in rs],
                **{k: _mean(rs, k) for k in _METRICS},
                "iou_seeds": ious,
                "iou_min": min(ious),
                "iou_max": max(ious),
            }
        )
    return out


def suite_means(rows: Sequence[dict]) -> list[dict]:
    """Mean IoU / accuracy / 3D precision / recall per (kind, segmenter, method) over scenes
    (``rows``: one per scene, e.g. :func:`scene_means`)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["kind"], r["segmenter"], r["method"]), []).append(r)
    out = []
    for (kind, seg, m), rs in groups.items():
        out.append(
            {
                "kind": kind,
                "segmenter": seg,
                "method": m,
                "label": rs[0]["label"],
                "scenes": len({r["scene"] for r in rs}),
                **{k: _mean(rs, k) for k in _METRICS},
            }
        )
    return out


def check_targets(rows: Sequence[dict]) -> dict[str, Any]:
    """The suite's targets, evaluated on the oracle rows averaged over the seeds: DivAS
    full mean IoU ≥ 0.90 over the surfel suite; DivAS full ≥ both baselines on every
    scene (and, listed, in how many seeds); removing the thin path lowers the ribs IoU."""
    o = [r for r in rows if r["segmenter"] == "oracle" and r["kind"] == SceneKind.GS2D]
    # (targets of the 2DGS suite; 3DGS variants are reported without targets)
    if not o:
        return {}
    by = {(r["scene"], r["method"]): r["iou"] for r in scene_means(o)}
    per_seed = {(r["scene"], r["method"], r.get("seed")): r["iou"] for r in o}
    seeds = sorted({r.get("seed") for r in o}, key=lambda x: (x is None, x))
    scenes = sorted({r["scene"] for r in o})
    full = [by[(s, "full")] for s in scenes]

    def beats(s: str, get) -> bool:
        return bool(
            get(s, "full") >= get(s, "centre_vote") and get(s, "full") >= get(s, "contrib_vote")
        )

    out: dict[str, Any] = {
        "seeds": seeds,
        "mean_full_iou": float(np.mean(full)),
        "mean_full_iou_ge_0.90": bool(np.mean(full) >= 0.90),
    }
    # each claim only when its rows were run (`--no-ablations` runs no `no_thin` session)
    methods = {m for _, m in by}
    if {"centre_vote", "contrib_vote"} <= methods:
        out["full_beats_baselines"] = {s: beats(s, lambda a, m: by[(a, m)]) for s in scenes}
        out["full_beats_baselines_seeds"] = {
            s: sum(beats(s, lambda a, m, k=k: per_seed[(a, m, k)]) for k in seeds) for s in scenes
        }
    if "ribs" in scenes and ("ribs", "no_thin") in by:
        out["ribs_thin_path_helps"] = bool(by[("ribs", "no_thin")] < by[("ribs", "full")])
    return out

"""The NoC protocol (:mod:`.noc`) over the synthetic suite and the real-capture targets,
the split into a tuning half and a held-out half, the tables.

**The split** (fixed before any tuning; no choice is made on the held-out half). The
tuning half holds one case of each failure mode the default segmenter is tuned against
— ``ribs`` (a single click on a rib refused), ``wheel`` (a thin object a short distance
in front of a textured background), ``pedestal`` (an object on a support of another
material) and the ``guitar`` capture (an object on its stand; with the stand and the
neck) —; everything else is held out: the synthetic ``plant`` and ``occluded`` (a vase
on a plinth: the support case again) and the captures ``biker`` / ``biker_spz`` (the
helmet held beside the leg: an object against another) and ``lod1`` (plants on the
ground). A synthetic scene's 2DGS and 3DGS variants, and a capture's targets and its
other file formats, are in the same half.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .noc import NocConfig, NocRun, number_of_clicks, run_noc

__all__ = [
    "TUNING_SCENES",
    "HELD_OUT_SCENES",
    "TUNING_CAPTURES",
    "HELD_OUT_CAPTURES",
    "half_of",
    "NocCase",
    "synthetic_cases",
    "real_cases",
    "run_case",
    "run_cases",
    "summary",
    "noc_table",
]

TUNING_SCENES: tuple[str, ...] = ("ribs", "wheel", "pedestal")
HELD_OUT_SCENES: tuple[str, ...] = ("plant", "occluded")
TUNING_CAPTURES: tuple[str, ...] = ("guitar",)
HELD_OUT_CAPTURES: tuple[str, ...] = ("biker", "biker_spz", "lod1")


def half_of(name: str) -> str:
    """``"tuning"`` or ``"held-out"`` of a synthetic scene or a capture name."""
    if name in TUNING_SCENES or name in TUNING_CAPTURES:
        return "tuning"
    if name in HELD_OUT_SCENES or name in HELD_OUT_CAPTURES:
        return "held-out"
    raise ValueError(f"{name!r} is in neither half of the NoC split (noc_suite)")


@dataclass(frozen=True)
class NocCase:
    """One scene or target: ``name`` (``wheel/3dgs``, ``guitar/stand``), ``group`` (the
    scene or capture: its split half), ``kind`` (``2dgs``, ``3dgs`` or ``real``)."""

    name: str
    group: str
    kind: str

    @property
    def half(self) -> str:
        return half_of(self.group)


def synthetic_cases(scenes: Sequence[str], kinds: Sequence[str]) -> list[NocCase]:
    return [NocCase(f"{s}/{k}", s, k) for s in scenes for k in kinds]


def real_cases(only: Sequence[str] | None = None) -> list[NocCase]:
    """Every real target (``capture/target``), or those in ``only``."""
    from .real_target_defs import CAPTURES

    out = []
    for cap, c in CAPTURES.items():
        for t in c.targets:
            name = f"{cap}/{t.name}"
            if only is None or name in only:
                out.append(NocCase(name, cap, "real"))
    return out


def run_case(
    case: NocCase,
    segmenter: str,
    *,
    size: int = 20_000,
    seed: int = 0,
    config: NocConfig = NocConfig(),
    data_dir: Path | None = None,
    device=None,
    log: Callable[[str], None] | None = None,
    cache: dict | None = None,
) -> NocRun:
    """One NoC run of ``segmenter`` on a case. Synthetic: the scene generated in memory,
    the session's own anchor plan, its test cameras. Real (``data_dir``: ``tests/data``):
    the target's hand-placed anchor cameras (their clicks unused), its evaluation
    cameras, its don't-care Gaussians when the label file has them. ``cache``: scenes,
    renderers and cameras kept between runs on the same case."""
    from ..render import make_renderer
    from .pipeline import make_segmenter

    cache = {} if cache is None else cache
    if case.name not in cache:
        cache.clear()  # one case's scene at a time
        cache[case.name] = _prepare(case, size, seed, data_dir, device)
    prep = cache[case.name]
    if "renderer" not in prep:
        prep["renderer"] = make_renderer(prep["scene"], device=device)
    return run_noc(
        prep["scene"],
        prep["cameras"],
        prep["labels"],
        prep["tests"],
        segmenter=make_segmenter(segmenter, seed),
        anchors=prep["anchors"],
        dont_care=prep["dont_care"],
        config=config,
        device=device,
        renderer=prep["renderer"],
        log=log,
    )


def run_cases(
    cases: Sequence[NocCase],
    segmenters: Sequence[str],
    *,
    size: int = 20_000,
    seed: int = 0,
    config: NocConfig = NocConfig(),
    data_dir: Path | None = None,
    device=None,
    log: Callable[[str], None] | None = None,
) -> list[dict]:
    """:func:`run_case` for every case and segmenter: one row each (the case, its half
    and kind, the segmenter, :meth:`NocRun.as_dict`); ``log`` gets a line per run."""
    rows, cache = [], {}
    for case in cases:
        for seg in segmenters:
            run = run_case(
                case,
                seg,
                size=size,
                seed=seed,
                config=config,
                data_dir=data_dir,
                device=device,
                cache=cache,
            )
            rows.append(
                {
                    "case": case.name,
                    "half": case.half,
                    "kind": case.kind,
                    "segmenter": seg,
                    **run.as_dict(config.thresholds),
                }
            )
            if log is not None:
                log(
                    f"{case.name} [{case.half}] {seg}: IoU "
                    + " ".join(f"{v:.2f}" for v in run.ious)
                    + f"  outcomes {run.outcomes}  ({run.seconds:.0f} s)"
                )
    return rows


def _prepare(case: NocCase, size: int, seed: int, data_dir: Path | None, device) -> dict:
    if case.kind != "real":
        from ..synthetic import generate_scene

        sc = generate_scene(case.group, size=size, seed=seed, kind=case.kind)
        return {
            "scene": sc.scene,
            "cameras": sc.cameras,
            "labels": sc.labels,
            "tests": sc.test_cameras,
            "anchors": None,
            "dont_care": None,
        }
    from ..io.load import load_scene
    from .real_target_defs import CAPTURES
    from .real_targets import (
        evaluation_cameras,
        oracle_anchors,
        read_targets,
        target_dont_care,
        target_scene_labels,
    )

    if data_dir is None:
        raise ValueError("real targets need data_dir (tests/data)")
    cap, name = case.name.split("/")
    c = CAPTURES[cap]
    scene = load_scene(Path(data_dir) / c.path)
    doc = read_targets(Path(data_dir) / "targets" / cap)
    labels = target_scene_labels(scene, doc, name)
    anchors = oracle_anchors(scene, c.true_up, doc["targets"][name]["anchors"])
    return {
        "scene": scene,
        "cameras": [],
        "labels": labels,
        "tests": evaluation_cameras(scene, labels, c.true_up, device=device),
        "anchors": [(cam, src, idx) for cam, src, idx, _ in anchors],
        "dont_care": target_dont_care(scene, doc, name),
    }


def summary(rows: Sequence[dict], thresholds: Sequence[float] = (0.85, 0.90)) -> dict:
    """Per (segmenter, half): mIoU after each click, mean NoC and failures per level."""
    out: dict[str, dict] = {}
    for seg in dict.fromkeys(r["segmenter"] for r in rows):
        for half in ("tuning", "held-out", "all"):
            rs = [r for r in rows if r["segmenter"] == seg and (half == "all" or r["half"] == half)]
            if not rs:
                continue
            ious = np.array([r["ious"] for r in rs], np.float64)
            out[f"{seg}|{half}"] = {
                "segmenter": seg,
                "half": half,
                "cases": len(rs),
                "miou": ious.mean(axis=0).tolist(),
                "noc": {
                    f"{t:g}": float(np.mean([number_of_clicks(r["ious"], t) for r in rs]))
                    for t in thresholds
                },
                "nof": {
                    f"{t:g}": int(sum(not any(v >= t for v in r["ious"]) for r in rs))
                    for t in thresholds
                },
            }
    return out


def _noc_cell(ious: Sequence[float], t: float) -> str:
    k = number_of_clicks(ious, t)
    return f"{k}" if any(v >= t for v in ious) else f">{len(ious)}"


def noc_table(rows: Sequence[dict], thresholds: Sequence[float] = (0.85, 0.90)) -> str:
    """Markdown: per segmenter and half, a row per case (IoU after 1, 3, 5, 10 clicks,
    NoC per level; ``>10``: not reached) and the half's mean row."""
    lines = []
    summ = summary(rows, thresholds)
    tcols = " | ".join(f"NoC@{round(t * 100)}" for t in thresholds)
    for seg in dict.fromkeys(r["segmenter"] for r in rows):
        for half in ("tuning", "held-out"):
            rs = [r for r in rows if r["segmenter"] == seg and r["half"] == half]
            if not rs:
                continue
            n = len(rs[0]["ious"])
            ks = [k for k in (1, 3, 5, 10) if k <= n]
            lines.append(f"\n**{seg}, {half} half**\n")
            lines.append(
                "| case | " + " | ".join(f"IoU@{k}" for k in ks) + f" | {tcols} | clicks (+/−) |"
            )
            lines.append("|---|" + "---:|" * (len(ks) + len(thresholds)) + "---|")
            for r in rs:
                cells = [f"{r['ious'][k - 1]:.3f}" for k in ks]
                cells += [_noc_cell(r["ious"], t) for t in thresholds]
                pos = sum(1 for c in r["clicks"] if c is not None and c[2])
                neg = sum(1 for c in r["clicks"] if c is not None and not c[2])
                lines.append(f"| {r['case']} | " + " | ".join(cells) + f" | {pos}/{neg} |")
            s = summ[f"{seg}|{half}"]
            cells = [f"**{s['miou'][k - 1]:.3f}**" for k in ks]
            cells += [
                f"**{s['noc'][f'{t:g}']:.2f}** ({s['nof'][f'{t:g}']} >{n})" for t in thresholds
            ]
            lines.append("| mean | " + " | ".join(cells) + " | |")
    return "\n".join(lines)

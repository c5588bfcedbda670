"""The ``divas eval`` table as Markdown (rows of :mod:`.suite`)."""

from __future__ import annotations

from typing import Any

from ..kinds import SceneKind

__all__ = ["markdown_table"]


def _f(x) -> str:
    return "–" if x is None else f"{x:.3f}"


def _psnr(x) -> str:
    return "–" if x is None else f"{x:.1f}"


def markdown_table(result: dict[str, Any]) -> str:
    """The rows as a Markdown table, then the suite means and the targets."""
    seeds = sorted({r.get("seed") for r in result["rows"]}, key=lambda x: (x is None, x))
    multi = len(seeds) > 1
    fid = any("alpha_fidelity" in r for r in result["rows"])
    lines = [
        "| scene | "
        + ("seed | " if multi else "")
        + "segmenter | method | IoU | acc | P₃D | R₃D | "
        + ("α-fid | op-IoU | PSNR | " if fid else "")
        + "views |",
        "|---|"
        + ("---:|" if multi else "")
        + "---|---|---:|---:|---:|---:|"
        + ("---:|---:|---:|" if fid else "")
        + "---:|",
    ]
    for r in result["rows"]:
        sc = r["scene"] + (
            " (NeRF grid)"
            if r["kind"] == SceneKind.NERF
            else " (3DGS)"
            if r["kind"] == SceneKind.GS3D
            else ""
        )
        lines.append(
            f"| {sc} | "
            + (f"{r.get('seed')} | " if multi else "")
            + f"{r['segmenter']} | {r['label']} | {_f(r['iou'])} | "
            f"{_f(r['accuracy'])} | {_f(r['precision_3d'])} | {_f(r['recall_3d'])} | "
            + (
                f"{_f(r.get('alpha_fidelity'))} | {_f(r.get('opacity_weighted_iou'))} | "
                f"{_psnr(r.get('psnr'))} | "
                if fid
                else ""
            )
            + f"{r.get('views_fused', '–')}/{r.get('views', '–')} |"
        )
    if multi and result.get("scene_means"):
        lines += [
            "",
            f"Mean over seeds {', '.join(map(str, seeds))} (min–max):",
            "",
            "| scene | segmenter | method | IoU | IoU min–max | acc | P₃D | R₃D |",
            "|---|---|---|---:|---:|---:|---:|---:|",
        ]
        for r in result["scene_means"]:
            sc = r["scene"] + (" (NeRF grid)" if r["kind"] == SceneKind.NERF else "")
            lines.append(
                f"| {sc} | {r['segmenter']} | {r['label']} | {_f(r['iou'])} | "
                f"{_f(r['iou_min'])}–{_f(r['iou_max'])} | {_f(r['accuracy'])} | "
                f"{_f(r['precision_3d'])} | {_f(r['recall_3d'])} |"
            )
    means = result.get("means") or []
    if means:
        lines += [
            "",
            "Mean over scenes:",
            "",
            "| kind | segmenter | method | scenes | IoU | acc | P₃D | R₃D |",
            "|---|---|---|---:|---:|---:|---:|---:|",
        ]
        for m in means:
            lines.append(
                f"| {m['kind']} | {m['segmenter']} | {m['label']} | {m['scenes']} | "
                f"{_f(m['iou'])} | {_f(m['accuracy'])} | {_f(m['precision_3d'])} | "
                f"{_f(m['recall_3d'])} |"
            )
    cfg = result.get("config") or {}
    if cfg.get("protocol"):
        u = cfg.get("user") or {}
        lines += [
            "",
            f"View protocol: {cfg['protocol']}"
            + (
                ""
                if cfg["protocol"] != "user"
                else " (simulated user on the session's anchor plan: "
                + (
                    f"≤ {u['clicks_per_anchor']} clicks per anchor"
                    if u.get("clicks_per_anchor")
                    else f"each anchor until complete or {u.get('max_failed_clicks')} clicks "
                    "without progress"
                )
                + ", ≤ "
                + (f"{u['max_views']}" if u.get("max_views") else "10 (forward-facing) / 20 (360°)")
                + " views, regions ≥ "
                f"{100 * u.get('min_region_frac', 0):.1f} % of the view, negative clicks "
                f"{'on' if u.get('negative_clicks') else 'off'}, "
                + (
                    "then the other supported Fibonacci anchors"
                    if u.get("more_anchors")
                    else "offered anchors only"
                )
                + (
                    f", then ≤ {u['manual_anchors']} training cameras as manual anchors)"
                    if u.get("manual_anchors")
                    else ")"
                )
            ),
        ]
    t = result.get("targets") or {}
    if t:
        lines += [
            "",
            "Targets (oracle"
            + (", means over the seeds" if multi else "")
            + "): mean DivAS-full IoU "
            f"{t['mean_full_iou']:.3f} (≥ 0.90: {'yes' if t['mean_full_iou_ge_0.90'] else 'NO'})"
            + (
                ""
                if "full_beats_baselines" not in t
                else "; ≥ both baselines: "
                + ", ".join(
                    f"{s} {'yes' if ok else 'NO'}"
                    + (
                        f" ({t['full_beats_baselines_seeds'][s]}/{len(t['seeds'])} seeds)"
                        if len(t.get("seeds", ())) > 1
                        else ""
                    )
                    for s, ok in t["full_beats_baselines"].items()
                )
            )
            + (
                ""
                if "ribs_thin_path_helps" not in t
                else f"; thin path raises ribs IoU: {'yes' if t['ribs_thin_path_helps'] else 'NO'}"
            ),
        ]
    return "\n".join(lines)

"""The ``divas demo`` clicks: prompts from a synthetic scene's metadata click points.

Shared by ``divas demo`` and the evaluation's ``"clicks"`` protocol
(:func:`~.pipeline.scripted_anchors`), so both place the same anchors and clicks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..session import AnchorPrompt, Click, Prompts

__all__ = ["demo_prompts"]


def demo_prompts(metadata: dict, cameras: Sequence[Camera], views_per_click: int = 3) -> Prompts:
    """Prompts from the synthetic metadata: each click point goes on ``views_per_click``
    training cameras that see it and frame it, taken at evenly spread positions of its
    ``visible_in`` list (click ``k``, copy ``j`` of ``n·m``: position ``(2(k·m+j)+1)/(2n·m)``,
    the next framing camera when that one does not); clicks on the same camera share an
    anchor. Each (click, camera) pair is one centroid view."""
    by_name = {c.name: c for c in cameras}
    clicks = metadata["clicks"]
    m = max(1, int(views_per_click))
    total = len(clicks) * m
    groups: dict[str, list[Click]] = {}
    for k, c in enumerate(clicks):
        vis = [n for n in c["visible_in"] if n in by_name]
        used: set[str] = set()
        for j in range(m):
            start = len(vis) * (2 * (k * m + j) + 1) // (2 * total) if vis else 0
            for step in range(len(vis)):
                name = vis[(start + step) % len(vis)]
                if name in used:
                    continue
                cam = by_name[name]
                uv, z = cam.project(np.array([c["xyz"]]))
                x, y = uv[0]
                if z[0] > 0 and 0 <= x < cam.width and 0 <= y < cam.height:
                    groups.setdefault(name, []).append(Click((float(x), float(y))))
                    used.add(name)
                    break
    if not groups:
        raise DivasInputError(None, "no metadata click is visible in a training camera")
    return Prompts(tuple(AnchorPrompt("training_camera", n, tuple(cs)) for n, cs in groups.items()))

"""The engine's fixed vocabularies as enums: scene kinds, view statuses, why a view
was rejected and where a click was made.

Both are :class:`enum.StrEnum`, so a member equals its string value and serialises to
it: session files, reports and prompts files keep the strings they always had.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["SceneKind", "ViewStatus", "RejectReason", "ClickOrigin"]


class SceneKind(StrEnum):
    """What a scene is made of.

    ``GS2D`` native 2DGS surfels; ``GS3D`` trained 3D Gaussians (loaded flattened to
    surfels, NOTES "Conventions", with the dropped axis kept in ``SurfelScene.scale_n``);
    ``NERF`` a density grid. A session on either Gaussian kind runs the surfel path of
    the paper (its kind is ``GS2D``); ``NERF`` runs the density-grid path.
    """

    GS2D = "2dgs"
    GS3D = "3dgs"
    NERF = "nerf"


class ViewStatus(StrEnum):
    """Where a centroid view is in the loop (paper Sec. 3.3-3.5).

    ``OPEN`` spawned, awaiting accept; ``PENDING`` accepted, its 2D segmentation still
    running (NeRF background worker); ``FUSED`` accepted and fused into the grid;
    ``REJECTED`` accept refused (the segmenter's score below the threshold).
    """

    OPEN = "open"
    PENDING = "pending"
    FUSED = "fused"
    REJECTED = "rejected"

    @property
    def accepted(self) -> bool:
        """Accepted by the user (fused, or fusing once its mask arrives)."""
        return self in (ViewStatus.FUSED, ViewStatus.PENDING)


class RejectReason(StrEnum):
    """Why an accepted view was not fused (the numbers travel in
    :class:`~divas_engine.segment.base.Rejection`).

    ``NO_POSITIVE_PROMPT`` its prompts hold no positive point; ``LOW_SCORE`` the kept
    mask channel scored below the threshold (Sec. 3.4); ``EMPTY_MASK`` too few pixels
    left after depth weighting; ``SEGMENTATION_FAILED`` the segmenter raised;
    ``SEGMENTATION_MISSING`` the segmenter returned nothing for the view.
    """

    NO_POSITIVE_PROMPT = "no-positive-prompt"
    LOW_SCORE = "low-score"
    EMPTY_MASK = "empty-mask"
    SEGMENTATION_FAILED = "segmentation-failed"
    SEGMENTATION_MISSING = "segmentation-missing"


class ClickOrigin(StrEnum):
    """Where a click of the session was made (each click is a 3D constraint,
    :mod:`divas_engine.session.corrections`).

    ``ANCHOR`` on an anchor render (a positive one spawns a centroid view, Sec. 3.3);
    ``VIEW`` on a centroid view; ``CAMERA`` through any other camera (a free 3D view);
    ``POINT`` a world point given directly.
    """

    ANCHOR = "anchor"
    VIEW = "view"
    CAMERA = "camera"
    POINT = "point"

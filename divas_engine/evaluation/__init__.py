"""Evaluation of DivAS against ground truth (NOTES "Evaluation", paper App. D protocol).

* :mod:`.metrics` — rendered-mask IoU / pixel accuracy per test view and per scene,
  per-primitive precision / recall (:class:`ViewEvaluator`).
* :mod:`.render_scores` — those scores in the report format of ``divas demo``.
* :mod:`.baselines` — peer baselines fed the same accepted view masks: centre-projection
  voting and FlashSplat-style contribution-weighted voting.
* :mod:`.scripted_user` — the simulated user of the paper's interactive protocol
  (Sec. 3.3/3.7): clicks uncovered target regions under the overlay, anchor by anchor.
* :mod:`.pipeline` — scripted :class:`~divas_engine.session.Session` runs on the
  synthetic scenes (and the ablation variants).
* :mod:`.suite` — the ``divas eval`` table.
* :mod:`.ground_truth` — ground-truth labels from ``.npy`` in scene order (the oracle's
  target, the 3D scores' reference).
* :mod:`.demo_prompts` — the ``divas demo`` clicks from a synthetic scene's metadata.
"""

from .baselines import (
    BaselineResult,
    CentreVoteConfig,
    ContributionVoteConfig,
    ContributionVoter,
    MaskView,
    centre_vote,
    contribution_vote,
)
from .demo_prompts import demo_prompts
from .ground_truth import load_ground_truth
from .metrics import (
    EvalConfig,
    SceneScores,
    ViewEvaluator,
    ViewScore,
    evaluate_selection,
    ground_truth_masks,
    mask_scores,
    predicted_masks,
    segmented_grid,
    surfel_scores,
)
from .render_scores import MaskScores, render_iou
from .scripted_user import ScriptedUser, UserBudget, UserLog

__all__ = [
    "EvalConfig",
    "SceneScores",
    "ViewEvaluator",
    "ViewScore",
    "evaluate_selection",
    "ground_truth_masks",
    "mask_scores",
    "predicted_masks",
    "segmented_grid",
    "surfel_scores",
    "MaskScores",
    "render_iou",
    "BaselineResult",
    "CentreVoteConfig",
    "ContributionVoteConfig",
    "ContributionVoter",
    "MaskView",
    "centre_vote",
    "contribution_vote",
    "ScriptedUser",
    "UserBudget",
    "UserLog",
    "demo_prompts",
    "load_ground_truth",
]

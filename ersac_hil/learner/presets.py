"""Named learner settings (``ersac-hil daemon --learner NAME``), docs/learner.md "The default".

- ``paper``: the paper's Algorithm 1 exactly: no move guard, no interleaved search, the
  last iterate is the final policy.
- ``guarded``: Algorithm 1 with the move guard (no update moves a parameter by more than
  ``MAX_STEP`` sigma): the daemon's default before ``select``.
- ``select``: the guarded rule with interleaved offline search after every update
  (``interleave_every`` 1) and, at a kappa > 0, when the episode budget is spent, the
  offline selection of the run's kappa adopted as the final policy (``Selection`` over every
  episode of the run, the trust region around them; among its argmin and the observed
  policies the one of lowest F~ + kappa sd(F~): risk averse about the model's own
  uncertainty too, so that it does not pick an edge the data barely reach). The last iterate
  of a single run is a noisy stochastic-approximation path; the selection is the policy the
  run's data support. At kappa 0 the last iterate stays (the selection, confined to the
  data, measured worse there: docs/learner.md).

- ``trust``: ``select`` with a trust-region step along F~ in place of the confidence-gated
  greedy move: after every update theta moves to the argmin of the update's F~ within
  2 sqrt(d) sigma of the gradient step's theta whenever F~ is lower there (``GreedyRule``
  z 0, around theta). Measured on the bracing surrogate only (docs/learner.md): nearer the
  kappa 2 optimum than ``select``, still short of the kappa 0 target; not a default.

Per task default (:data:`TASK_LEARNER`): bracing ``select`` (measured: docs/learner.md),
lifting ``guarded`` (the interleaved search did worse on lifting, docs/learner.md).
"""
from __future__ import annotations

from dataclasses import dataclass

from .ersac import MAX_STEP, GreedyRule

__all__ = ["LearnerPreset", "PRESETS", "TASK_LEARNER", "preset"]


@dataclass(frozen=True)
class LearnerPreset:
    """``max_step`` (sigma units, None: no guard), ``interleave_every`` (0: off),
    ``final_selection`` (at a kappa > 0, adopt the offline selection at the end of the
    budget, with ``SelectionConfig.pessimism`` = kappa), ``greedy`` (how the interleaved
    search moves; None: ``GreedyRule()``, the confidence-gated move)."""

    name: str
    max_step: float | None
    interleave_every: int
    final_selection: bool
    greedy: GreedyRule | None = None


PRESETS: dict[str, LearnerPreset] = {
    "paper": LearnerPreset("paper", None, 0, False),
    "guarded": LearnerPreset("guarded", MAX_STEP, 0, False),
    "select": LearnerPreset("select", MAX_STEP, 1, True),
    "trust": LearnerPreset("trust", MAX_STEP, 1, True, GreedyRule(z=0.0, radius=2.0, min_move=0.0, around="theta")),
}
#: The default learner of a new run per task.
TASK_LEARNER: dict[str, str] = {"bracing": "select", "lifting": "guarded"}
#: What a run stored before learners had names was made with.
LEGACY_LEARNER = "guarded"


def preset(name: str) -> LearnerPreset:
    """The preset ``name`` (``KeyError`` naming the known ones)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown learner {name!r}; known: {', '.join(PRESETS)}") from None

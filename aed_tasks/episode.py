"""One episode as the expert (or a policy) produced it, in memory.

Arrays follow ManiSkill's trajectory convention: T actions and per-step arrays (success,
fail, stage, error_label) describe the state *after* each action; observations have T + 1
entries (the reset frame first). `frame_labels()` gives the label of every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ROLES = ("demo", "agent_success", "agent_failure", "explore", "policy_rollout")


@dataclass
class Episode:
    env_id: str
    task: str
    split: str
    env_index: int
    seed: int
    demonstrator: bool
    control_mode: str
    actions: np.ndarray  # (T, 4) float32
    success: np.ndarray  # (T,) bool
    fail: np.ndarray  # (T,) bool
    stage: np.ndarray  # (T,) int16
    error_label: np.ndarray  # (T,) uint8: 1 from the intervention on
    error_kind: str | None = None
    error_onset: int | None = None  # index of the first intervened action
    rgb: dict[str, np.ndarray] = field(default_factory=dict)  # camera -> (T + 1, H, W, 3) uint8
    depth: dict[str, np.ndarray] = field(
        default_factory=dict
    )  # camera -> (T + 1, H, W, 1) int16 mm
    expert_speed: float = 0.0
    suboptimal: bool = False  # a failed first attempt, then success (demonstration quality)
    truncated: bool = False  # the time limit cut the episode (a script that did not finish)
    outcome_problem: str = (
        ""  # why an intervened episode's end is not its named failure ('' when it is)
    )
    # sub-optimal demonstrations: where the failed first attempt ended, its kind, and why it
    # did not fail as named ('' when it did)
    first_attempt_steps: int | None = None
    first_attempt_kind: str | None = None
    first_attempt_problem: str = ""
    # the arm visits random poses instead of doing the task (`aed_tasks.expert.explore`)
    explore: bool = False

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def succeeded(self) -> bool:
        return bool(len(self.success) and self.success[-1])

    @property
    def failed_irrecoverably(self) -> bool:
        return bool(len(self.fail) and self.fail[-1])

    def frame_labels(self) -> np.ndarray:
        return frame_labels(self.error_label)

    @property
    def role(self) -> str:
        if self.demonstrator:
            return "demo"
        if self.explore:
            return "explore"
        return "agent_failure" if self.error_kind is not None else "agent_success"


# --- the frame-label rule (one place) ------------------------------------------------------------
def frame_labels(action_labels: np.ndarray) -> np.ndarray:
    """(T,) labels of the actions -> (T + 1,) labels of the frames: the reset frame is normal,
    frame t + 1 is the one action t led to."""
    return np.concatenate([[0], np.asarray(action_labels)]).astype(np.uint8)


def onset_frame(error_onset: int | None) -> int | None:
    """The first error frame of an episode whose error starts at action `error_onset`."""
    return None if error_onset is None else int(error_onset) + 1


def frame_labels_from_onset(num_frames: int, error_onset: int | None) -> np.ndarray:
    """(num_frames,) bool labels of an episode known only by its error onset (None: no error)."""
    labels = np.zeros(num_frames, dtype=bool)
    first = onset_frame(error_onset)
    if first is not None:
        labels[first:] = True
    return labels

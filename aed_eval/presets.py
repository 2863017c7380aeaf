"""The protocol's counts, one named preset a profile: how many environments, episodes and
rollouts each command records. Every command takes its defaults from here (the models' sizes
and training recipes are the models' own: `aed_models.recipe`).

- `paper`: the paper's protocol (every environment, 5 demonstrations, 20 successes and 20
  failures per base environment, 20 rollouts per novel environment), for a GPU machine;
- `mini`: CPU-sized counts for one task's experiments;
- `demo`: what `aed demo` runs end to end in under 20 minutes on two cores.
"""

from __future__ import annotations

from dataclasses import dataclass

from aed_models.recipe import check_profile


@dataclass
class Protocol:
    """Counts of one profile (per environment unless said).

    Args:
        train_envs: base environments the models train on, at most (0, or a catalogue too
            small for it: all but the calibration ones).
        calibration_envs: further base environments, held out of all training, for calibration.
        novel_envs: novel environments collected and rolled out in, at most (0: all).
        num_demos: demonstrations per environment (and given to the policy and detectors).
        num_successes: expert (agent) successes per base environment.
        num_failures: expert (agent) failures per training environment.
        num_explore: exploration episodes per training environment (`aed collect
            --num-explore`), for the scene encoder that the CPU-sized policies read.
        labelled: labelled expert successes and failures (each) per novel environment.
        rollouts: policy rollouts per novel environment.
        calibration_rollouts: policy rollouts per calibration environment.
        policies: the policies `aed demo` trains and rolls out.
    """

    train_envs: int
    calibration_envs: int
    novel_envs: int
    num_demos: int
    num_successes: int
    num_failures: int
    num_explore: int
    labelled: int
    rollouts: int
    calibration_rollouts: int
    policies: tuple[str, ...]

    def training_envs(self, catalogue_size: int) -> int:
        """Base environments the models train on: the first ones of a collection."""
        available = catalogue_size - self.calibration_envs
        return min(self.train_envs, available) if self.train_envs else available

    def base_envs(self, catalogue_size: int) -> int:
        """Base environments a collection covers: training and calibration ones."""
        return self.training_envs(catalogue_size) + self.calibration_envs

    def rollout_envs(self, catalogue_size: int) -> int:
        """Novel environments collected and rolled out in."""
        return min(self.novel_envs, catalogue_size) if self.novel_envs else catalogue_size


PROTOCOLS: dict[str, Protocol] = {
    "paper": Protocol(
        train_envs=0,
        calibration_envs=4,
        novel_envs=0,
        num_demos=5,
        num_successes=20,
        num_failures=20,
        num_explore=0,
        labelled=5,
        rollouts=20,
        calibration_rollouts=20,
        policies=("naive_dc", "dct", "scan"),
    ),
    "mini": Protocol(
        train_envs=23,
        calibration_envs=4,
        novel_envs=18,
        num_demos=5,
        num_successes=10,
        num_failures=10,
        num_explore=12,
        labelled=1,
        rollouts=5,
        calibration_rollouts=10,
        policies=("naive_dc", "dct", "scan"),
    ),
    "demo": Protocol(
        train_envs=5,
        calibration_envs=3,
        novel_envs=6,
        num_demos=3,
        num_successes=4,
        num_failures=3,
        num_explore=6,
        labelled=3,
        rollouts=4,
        calibration_rollouts=4,
        policies=("dct",),
    ),
}


def protocol(profile: str) -> Protocol:
    return PROTOCOLS[check_profile(profile)]

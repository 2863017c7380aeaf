"""`aed collect`: the protocol's episodes, recorded by the scripted expert in every environment.

For a task and split, in each chosen environment of the catalogue:

- `demo`: expert demonstrations (the demonstrator's appearance, length-variant speed profile);
- `demo` with `suboptimal`: a failed first attempt, then success (demonstration quality);
- `agent_success`: the agent's appearance, the clean expert;
- `agent_failure`: the agent's appearance, the expert intervened at the critical moment,
  the task's error kinds rotated so that every kind is represented evenly.

Work is cut into shards of at most `shard_size` episodes of one (environment, role), recorded
by `aed_eval.producer` (atomic shards, resumable, worker-count independent); seeds derive only
from (seed, task, split, environment, role, episode index, attempt). Workers are local
processes, or Ray actors on a cluster (`ray` extra; the output folder must then be on a
filesystem every node sees).
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from aed_eval.checks import task_class
from aed_eval.presets import protocol
from aed_eval.producer import EpisodeRunner, ProductionSummary, ShardResult, produce
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import trajectory

logger = logging.getLogger(__name__)

GROUPS = ("demo", "demo_suboptimal", "agent_success", "agent_failure", "explore")
IDENTITY = ("task", "split", "seed", "obs_mode", "cameras", "shard_size")  # must match to resume


@dataclass
class CollectConfig:
    """What `aed collect` records, and how (counts are per environment). Build it with
    `from_preset`: the profile's counts (`aed_eval.presets`; the novel split records
    demonstrations only) and the layout's output folder."""

    task: str
    """Task name (e.g. PickPlace)."""
    split: Literal["base", "novel"]
    """Catalogue split."""
    profile: Profile
    """The preset the counts came from (paper, mini, demo)."""
    out: Path
    """Output folder. Re-running resumes into it."""
    num_envs: int
    """Use the first N environments of the catalogue (ignored when `envs` are given)."""
    num_demos: int
    """Expert demonstrations per environment."""
    num_successes: int
    """Agent successes per environment."""
    num_failures: int
    """Agent failures per environment (error kinds rotated evenly)."""
    envs: tuple[int, ...] = ()
    """Explicit environment indices (default: the first `num_envs`)."""
    num_suboptimal_demos: int = 0
    """Sub-optimal demonstrations per environment (failed first attempt, then success)."""
    num_explore: int = 0
    """Exploration episodes per environment (the arm visits random poses; frames for the scene
    encoder, `aed_tasks.expert.explore`)."""
    shard_size: int = 10
    """Episodes per shard file (the unit of atomic writes and of resuming)."""
    workers: int = 1
    """Parallel workers (1: in this process)."""
    executor: Literal["local", "ray"] = "local"
    """local: a process pool on this machine; ray: Ray actors (pip install aed-toolkit[ray])."""
    ray_address: str | None = None
    """Ray cluster address (None: start or join a local Ray)."""
    obs_mode: str = "rgbd"
    """ManiSkill observation mode recorded (training needs rgbd)."""
    cameras: tuple[str, ...] = ("front",)
    """Cameras rendered and recorded (front, front_shift)."""
    compression: Literal["gzip", "lzf"] = "gzip"
    """HDF5 filter of images: gzip is smaller, lzf faster."""
    compression_level: int = 4
    """gzip level, 0-9."""
    record_env_states: bool = True
    """Record env states (replay with --use-env-states); costs little."""
    seed: int = 0
    """Root seed; every episode's seed derives from it deterministically."""
    max_attempts: int = 5
    """Tries per episode (new seed each) before the expert is declared unable."""
    max_retry_rate: float = 0.2
    """Retries (rejected tries) per recorded episode above which the collection fails loudly."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self) -> None:
        from aed_tasks.base_env import CAMERAS

        task_cls = task_class(self.task)
        self.task = task_cls.task_name
        if self.split not in task_cls.catalogue_sizes:
            raise ValueError(
                f"split={self.split!r}: {self.task} has splits {sorted(task_cls.catalogue_sizes)}"
            )
        check_profile(self.profile)
        size = task_cls.catalogue_sizes[self.split]
        for name in (
            "num_demos",
            "num_successes",
            "num_failures",
            "num_suboptimal_demos",
            "num_explore",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 0")
        bad = [i for i in self.envs if not 0 <= i < size]
        if bad:
            raise ValueError(
                f"envs={self.envs}: {bad} outside {self.task}-{self.split}'s 0..{size - 1}"
            )
        if len(set(self.envs)) != len(self.envs):
            raise ValueError(f"envs={self.envs}: duplicates")
        if not self.envs and not 1 <= self.num_envs <= size:
            raise ValueError(
                f"num_envs={self.num_envs}: must be in 1..{size} ({self.task}-{self.split})"
            )
        if self.num_failures and not task_cls.error_kinds:
            raise ValueError(
                f"num_failures={self.num_failures}: {self.task} declares no error kinds"
            )
        if self.num_suboptimal_demos and not task_cls.recoverable_errors:
            raise ValueError(
                f"num_suboptimal_demos={self.num_suboptimal_demos}: {self.task} has no "
                "recoverable errors"
            )
        if not 0.0 <= self.max_retry_rate:
            raise ValueError(f"max_retry_rate={self.max_retry_rate}: must be >= 0")
        for name in ("shard_size", "workers", "max_attempts"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        if not 0 <= self.compression_level <= 9:
            raise ValueError(f"compression_level={self.compression_level}: must be in 0..9")
        unknown = sorted(set(self.cameras) - set(CAMERAS))
        if unknown or not self.cameras:
            raise ValueError(f"cameras={self.cameras}: unknown {unknown}; known {sorted(CAMERAS)}")
        if self.executor not in ("local", "ray"):
            raise ValueError(f"executor={self.executor!r}: local or ray")
        self.cameras = tuple(self.cameras)
        self.envs = tuple(int(i) for i in self.envs)
        self.out = Path(self.out)

    @classmethod
    def from_preset(
        cls,
        task: str = "PickPlace",
        split: str = "base",
        profile: str = "mini",
        runs: Path = Path("runs"),
        **overrides: Any,
    ) -> CollectConfig:
        """The profile's counts for `split` (novel: demonstrations only), the layout's output
        folder under `runs`, then `overrides`."""
        counts = protocol(profile)
        task = task_class(task).task_name
        size = task_class(task).catalogue_sizes.get(split, 0)
        base = split == "base"
        preset = {
            "task": task,
            "split": split,
            "profile": profile,
            "out": RunLayout(runs).data(task, split),
            "num_envs": counts.base_envs(size) if base else counts.rollout_envs(size),
            "num_demos": counts.num_demos,
            "num_successes": counts.num_successes if base else 0,
            "num_failures": counts.num_failures if base else 0,
            "num_explore": counts.num_explore if base else 0,
        }
        return cls(**{**preset, **overrides})

    def env_indices(self) -> list[int]:
        return list(self.envs) if self.envs else list(range(self.num_envs))

    def counts(self) -> dict[str, int]:
        return {
            "demo": self.num_demos,
            "demo_suboptimal": self.num_suboptimal_demos,
            "agent_success": self.num_successes,
            "agent_failure": self.num_failures,
            "explore": self.num_explore,
        }

    def identity(self) -> dict[str, Any]:
        return {k: plain_value(getattr(self, k)) for k in IDENTITY}

    def to_dict(self) -> dict[str, Any]:
        return {k: plain_value(v) for k, v in asdict(self).items()}


def plain_value(x: Any) -> Any:
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, tuple):
        return list(x)
    return x


# --- shards and seeds --------------------------------------------------------------------------
@dataclass(frozen=True)
class Shard:
    """At most `shard_size` consecutive episodes (indices start..start+count-1) of one env and
    role."""

    task: str
    split: str
    env_index: int
    group: str  # one of GROUPS
    start: int
    count: int

    @property
    def stem(self) -> str:
        return f"{self.group}_env{self.env_index:03d}_{self.start:04d}"

    @property
    def role(self) -> str:
        return "demo" if self.group.startswith("demo") else self.group

    @property
    def demonstrator(self) -> bool:
        return self.role == "demo"

    @property
    def suboptimal(self) -> bool:
        return self.group == "demo_suboptimal"

    def indices(self) -> range:
        return range(self.start, self.start + self.count)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def plan_shards(cfg: CollectConfig) -> list[Shard]:
    """Every shard of the request, environment by environment."""
    shards = []
    for env_index in cfg.env_indices():
        for group, count in cfg.counts().items():
            for start in range(0, count, cfg.shard_size):
                n = min(cfg.shard_size, count - start)
                shards.append(Shard(cfg.task, cfg.split, env_index, group, start, n))
    return shards


def episode_seed(
    root: int, task: str, split: str, env_index: int, group: str, k: int, attempt: int
) -> int:
    """A 31-bit seed from the episode's identity alone (same on any worker, in any order)."""
    key = f"{root}/{task}/{split}/{env_index}/{group}/{k}/{attempt}".encode()
    return int.from_bytes(hashlib.sha256(key).digest()[:4], "little") & 0x7FFFFFFF


def error_kind_for(kinds: tuple[str, ...], env_index: int, k: int) -> str:
    """Rotate the error kinds: per environment, counts differ by at most one; offset by env."""
    return kinds[(env_index + k) % len(kinds)]


# --- one worker --------------------------------------------------------------------------------
class CollectError(ValueError):
    """The expert could not produce a wanted episode within `max_attempts`, or needed too many
    retries."""


class ExpertRunner(EpisodeRunner):
    """The scripted expert's shards in one process, one env per appearance (gym.make costs
    seconds)."""

    def __init__(self, cfg: CollectConfig):
        super().__init__(cfg)
        self._envs: dict[bool, Any] = {}

    def env(self, shard: Shard) -> Any:
        return self.env_for(shard.demonstrator)

    def env_for(self, demonstrator: bool) -> Any:
        if demonstrator not in self._envs:
            import gymnasium as gym

            import aed_tasks

            env = gym.make(
                aed_tasks.env_id(self.cfg.task, self.cfg.split),
                demonstrator=demonstrator,
                obs_mode=self.cfg.obs_mode,
                cameras=tuple(self.cfg.cameras),
                # stored `terminated` flags must not mark successes alone
                terminate_on_success=False,
            )
            self._envs[demonstrator] = trajectory.make_step_recorder(
                env, self.cfg.record_env_states
            )
        return self._envs[demonstrator]

    def compression(self) -> trajectory.Compression:
        return trajectory.Compression(self.cfg.compression, self.cfg.compression_level)

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()

    def episode(self, shard: Shard, k: int) -> tuple[Any, trajectory.RecordedSteps, dict[str, Any]]:
        """One accepted episode and why earlier tries were rejected: a retry with the next seed
        when the expert cannot plan it or its outcome is not the role's (a clean expert that
        failed, an error that did not fail in its named way, a script cut by the time limit)."""
        from aed_tasks.expert import ErrorSpec, explore, solve

        env = self.env(shard)
        error = None
        if shard.role == "agent_failure":
            error = ErrorSpec(error_kind_for(env.unwrapped.error_kinds, shard.env_index, k))
        problem, rejected = "", []
        for attempt in range(self.cfg.max_attempts):
            seed = episode_seed(
                self.cfg.seed, shard.task, shard.split, shard.env_index, shard.group, k, attempt
            )
            try:  # frames=False: the step recorder around `env` keeps them
                if shard.role == "explore":
                    episode = explore(env, seed, env_index=shard.env_index, frames=False)
                else:
                    episode = solve(
                        env,
                        seed,
                        error=error,
                        env_index=shard.env_index,
                        suboptimal=shard.suboptimal,
                        frames=False,
                    )
            except RuntimeError as e:  # e.g. a script that never reached its error's moment
                problem = f"{type(e).__name__}: {e}"
            else:
                recorded = env.take()
                problem = _rejection(episode, shard)
                if not problem:
                    return (
                        episode,
                        recorded,
                        {"index": k, "attempt": attempt, "rejected": rejected, "shard": shard.stem},
                    )
            rejected.append(problem)
            logger.warning(
                "%s episode %d attempt %d (seed %d) rejected: %s",
                shard.stem,
                k,
                attempt,
                seed,
                problem,
            )
        raise CollectError(
            f"{shard.stem}: episode {k} failed {self.cfg.max_attempts} attempts; last: {problem}"
        )


def _rejection(episode: Any, shard: Shard) -> str:
    """Why the episode does not fit its role ('' when it does)."""
    if episode.env_index != shard.env_index:
        return f"ran in environment {episode.env_index}, not {shard.env_index}"
    if episode.truncated:
        return "the time limit cut the expert's script"
    if shard.role == "explore":
        return ""
    if shard.role == "agent_failure":
        if episode.succeeded:
            return "the intervened expert still succeeded"
        if episode.error_onset is None:
            return "no error onset"
        if episode.outcome_problem:
            return f"not a {episode.error_kind!r} failure: {episode.outcome_problem}"
        return ""
    if not episode.succeeded:
        return f"the expert did not succeed (stage {int(episode.stage.max(initial=0))})"
    if shard.suboptimal and episode.first_attempt_problem:
        return (
            f"the first attempt ({episode.first_attempt_kind}) did not fail as named: "
            f"{episode.first_attempt_problem}"
        )
    return ""


# --- the whole collection ----------------------------------------------------------------------
def run_collection(
    cfg: CollectConfig,
    on_shard_done: Callable[[ShardResult], None] | None = None,
    runner: ExpertRunner | None = None,
) -> ProductionSummary:
    """Record every planned shard that is not committed yet (resume = run again).

    `on_shard_done` is called after each commit; `runner` (workers=1 only) reuses the envs
    of an earlier call instead of making new ones.
    """
    if runner is not None and _env_key(runner.cfg) != _env_key(cfg):
        raise ValueError(
            f"runner made for {_env_key(runner.cfg)}, this collection needs {_env_key(cfg)}"
        )
    if runner is not None:
        runner.cfg = cfg
    summary = produce(
        cfg,
        plan_shards(cfg),
        ExpertRunner,
        f"collect {cfg.task}-{cfg.split}",
        on_done=on_shard_done,
        runner=runner,
    )
    check_retry_rate(Path(cfg.out), cfg.max_retry_rate)
    return summary


def retries(root: Path) -> tuple[int, int, Counter]:
    """(episodes, rejected tries, problems by count) of every committed shard of a folder."""
    episodes, rejected, problems = 0, 0, Counter()
    for shard in trajectory.scan_collection(root).shards:
        for entry in shard.body["episodes"]:
            episodes += 1
            rejected += int(entry.get("attempt", 0))
            problems.update(problem[:100] for problem in entry.get("rejected", []))
    return episodes, rejected, problems


def check_retry_rate(root: Path, max_rate: float) -> None:
    """Fail loudly when the experts needed too many retries: their behaviour is not what it
    claims."""
    episodes, rejected, problems = retries(root)
    if episodes and rejected / episodes > max_rate:
        common = "; ".join(f"{n}x {p}" for p, n in problems.most_common(3))
        raise CollectError(
            f"{root}: {rejected} rejected tries for {episodes} episodes ({rejected / episodes:.0%} "
            f"> max_retry_rate={max_rate:.0%}); most common: {common}"
        )


def _env_key(cfg: CollectConfig) -> tuple:
    return cfg.task, cfg.split, cfg.obs_mode, tuple(cfg.cameras), cfg.record_env_states


# --- command -----------------------------------------------------------------------------------
def collect(cfg: Annotated[CollectConfig, tyro.conf.arg(name="")]) -> int:
    """Record demonstrations, agent successes and agent failures (resumes into --out)."""
    start = time.perf_counter()
    summary = run_collection(cfg)
    seconds = time.perf_counter() - start
    print(
        f"{summary.out}: {summary.planned} shards ({summary.skipped} already there), "
        f"recorded {summary.episodes} episodes / {summary.steps} steps in {seconds:.1f} s"
    )
    return 0

"""`aed rollout`: phase 3 of the protocol, a trained policy acting in environments it never saw.

In every chosen environment of a split (the novel one by default), the policy runs N episodes
conditioned on that environment's demonstrations, which the demonstrator recorded with
`aed collect --split <split>` (`runs/<task>/data/<split>` by default). Episodes are stored in
the episode format with role `policy_rollout`, the env's `success` / `stage` per step, and
the policy's name and checkpoint sha256; frame labels are unknown in these environments and
stored as zeros with `labels_known: false`.

Every rollout runs the task's evaluation horizon (`AEDBaseEnv.eval_horizon`, twice the
longest clean expert episode) whatever happens, success latched at any step: ManiSkill's own
evaluation convention (terminations ignored, `success_once`). A rollout's length then tells
nothing of its outcome, so a detector cannot score well by knowing how long a rollout ran.
The first success and irrecoverable-failure steps are stored with each rollout, so the
paper's ending (stop at the first success) is a view of the same rollouts (`paper_ending`);
`--ending success` records that ending instead. Shards of (environment, index range) are
recorded by `aed_eval.producer`, as `aed collect`'s are.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from aed_eval.checks import check_camera, task_class
from aed_eval.collect import episode_seed, plain_value
from aed_eval.metrics import rate_interval
from aed_eval.presets import protocol
from aed_eval.producer import EpisodeRunner, ProductionSummary, produce
from aed_eval.scoring import Demonstrations
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import trajectory

logger = logging.getLogger(__name__)

ROLE = "policy_rollout"
IDENTITY = (
    "task",
    "split",
    "policy",
    "policy_sha256",
    "seed",
    "num_demos",
    "shard_size",
    "horizon",
    "ending",
)
ENDINGS = ("horizon", "success")


@dataclass
class RolloutConfig:
    """What `aed rollout` runs, and how (counts are per environment). Build it with
    `from_preset`: the profile's counts (`aed_eval.presets`), the task's evaluation horizon and
    the layout's paths."""

    task: str
    """Task name (e.g. PressButton)."""
    policy: str
    """Policy name (naive_dc, dct, scan)."""
    split: Literal["base", "novel"]
    """Catalogue split to act in."""
    profile: Profile
    """The preset the counts came from (paper, mini, demo)."""
    checkpoint: Path
    """Policy checkpoint."""
    demos: Path
    """Collection holding the split's demonstrations."""
    out: Path
    """Output folder. Re-running resumes into it."""
    num_envs: int
    """Use the first N environments that have demonstrations and, in the base split, that the
    policy did not train on (ignored when `envs` are given)."""
    num_episodes: int
    """Rollouts per environment."""
    num_demos: int
    """Demonstrations the policy is conditioned on (the first N of the environment's)."""
    horizon: int
    """Steps of every rollout (the task's evaluation horizon by default)."""
    envs: tuple[int, ...] = ()
    """Explicit environment indices."""
    num_suboptimal_demos: int = 0
    """Of the `num_demos`, how many are sub-optimal (the demonstration-quality experiment)."""
    suboptimal_demos: Path | None = None
    """Collection holding the sub-optimal demonstrations (default: `demos`)."""
    camera: str = "front"
    """Camera the policy sees through (front_shift: the viewpoint-shift experiment); the
    demonstrations must have been recorded through it (`aed collect --cameras`)."""
    shard_size: int = 10
    """Episodes per shard file (the unit of atomic writes and of resuming)."""
    workers: int = 1
    """Parallel workers (1: in this process)."""
    executor: Literal["local", "ray"] = "local"
    """local: a process pool on this machine; ray: Ray actors (pip install aed-toolkit[ray])."""
    ray_address: str | None = None
    """Ray cluster address."""
    ending: Literal["horizon", "success"] = "horizon"
    """horizon: every rollout runs `horizon` steps, success latched (the length tells nothing of
    the outcome); success: the paper's ending, a rollout stops at its first success (or an
    irrecoverable failure), so successful rollouts are shorter."""
    seed: int = 0
    """Root seed; every episode's seed derives from it (the same for every policy)."""
    progress: bool = True
    """Show a progress bar."""
    policy_sha256: tyro.conf.Suppress[str] = ""
    """The checkpoint's sha256, set by `run_rollouts` once it has checked the file."""

    def __post_init__(self) -> None:
        from aed_models.policies import POLICIES

        task_cls = task_class(self.task)
        self.task = task_cls.task_name
        POLICIES.check(self.policy)
        check_profile(self.profile)
        if self.ending not in ENDINGS:
            raise ValueError(f"ending={self.ending!r}: known {ENDINGS}")
        for name in ("num_envs", "num_episodes", "num_demos", "shard_size", "workers", "horizon"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        size = task_cls.catalogue_sizes[self.split]
        bad = [i for i in self.envs if not 0 <= i < size]
        if bad:
            raise ValueError(f"envs={bad}: {self.task}-{self.split} has environments 0..{size - 1}")
        if not 0 <= self.num_suboptimal_demos <= self.num_demos:
            raise ValueError(
                f"num_suboptimal_demos={self.num_suboptimal_demos}: 0..num_demos={self.num_demos}"
            )
        self.checkpoint, self.demos, self.out = (
            Path(self.checkpoint),
            Path(self.demos),
            Path(self.out),
        )
        if self.suboptimal_demos is not None:
            self.suboptimal_demos = Path(self.suboptimal_demos)
        check_camera(self.camera)

    @classmethod
    def from_preset(
        cls,
        task: str = "PressButton",
        policy: str = "naive_dc",
        split: str = "novel",
        profile: str = "mini",
        runs: Path = Path("runs"),
        **overrides: Any,
    ) -> RolloutConfig:
        """The profile's counts, the task's evaluation horizon, the layout's paths under `runs`,
        then `overrides`."""
        counts, task_cls, layout = protocol(profile), task_class(task), RunLayout(runs)
        task = task_cls.task_name
        preset = {
            "task": task,
            "policy": policy,
            "split": split,
            "profile": profile,
            "checkpoint": layout.policy(task, policy),
            "demos": layout.data(task, split),
            "out": layout.rollouts(task, policy, split),
            "num_envs": counts.rollout_envs(task_cls.catalogue_sizes[split]),
            "num_episodes": counts.rollouts,
            "num_demos": counts.num_demos,
            "horizon": task_cls.eval_horizon,
        }
        return cls(**{**preset, **overrides})

    def with_checkpoint_hash(self) -> RolloutConfig:
        """This config with the checkpoint's sha256 (a clear error when the file is missing)."""
        from aed_models.checkpoint import file_sha256

        if not self.checkpoint.is_file():
            raise FileNotFoundError(
                f"{self.checkpoint}: no policy checkpoint; train it with "
                f"`aed train-policy --task {self.task} --policy {self.policy}`"
            )
        return replace(self, policy_sha256=file_sha256(self.checkpoint))

    def identity(self) -> dict[str, Any]:
        identity = {k: plain_value(getattr(self, k)) for k in IDENTITY}
        if self.num_suboptimal_demos:  # only then, so folders written before it still resume
            identity["num_suboptimal_demos"] = self.num_suboptimal_demos
        if self.camera != "front":
            identity["camera"] = self.camera
        return identity

    def demonstrations(self) -> Demonstrations:
        """The demonstrations the policy is conditioned on, environment by environment."""
        roots = [self.demos]
        if self.suboptimal_demos is not None and self.suboptimal_demos != self.demos:
            roots.append(self.suboptimal_demos)
        return Demonstrations(
            roots, self.split, self.num_demos, self.num_suboptimal_demos, self.camera
        )

    def to_dict(self) -> dict[str, Any]:
        return {k: plain_value(v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class RolloutShard:
    """Rollouts start..start+count-1 of one environment."""

    task: str
    split: str
    env_index: int
    start: int
    count: int

    @property
    def stem(self) -> str:
        return f"{ROLE}_env{self.env_index:03d}_{self.start:04d}"

    def indices(self) -> range:
        return range(self.start, self.start + self.count)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def plan_shards(cfg: RolloutConfig, available: list[int]) -> list[RolloutShard]:
    if cfg.envs:
        missing = sorted(set(cfg.envs) - set(available))
        if missing:
            raise ValueError(
                f"environments {missing} have no demonstrations in {cfg.demos}; collect them with "
                f"`aed collect --task {cfg.task} --split {cfg.split} --envs ...`"
            )
        env_indices = list(cfg.envs)
    else:
        env_indices = sorted(available)[: cfg.num_envs]
    return [
        RolloutShard(
            cfg.task, cfg.split, env_index, start, min(cfg.shard_size, cfg.num_episodes - start)
        )
        for env_index in env_indices
        for start in range(0, cfg.num_episodes, cfg.shard_size)
    ]


class RolloutRunner(EpisodeRunner):
    """Runs rollout shards in one process: one env, one policy, the demos of each environment.

    `policy` replaces the checkpoint's policy (anything with `reset(demos)` and `act(obs)`;
    tests drive the real rollout code with scripted ones).
    """

    def __init__(self, cfg: RolloutConfig, policy: Any = None):
        import gymnasium as gym

        import aed_tasks
        from aed_models.policies import load_policy

        super().__init__(cfg if cfg.policy_sha256 else cfg.with_checkpoint_hash())
        self.policy = load_policy(cfg.checkpoint, name=cfg.policy) if policy is None else policy
        self.policy.camera = cfg.camera
        env = gym.make(
            aed_tasks.env_id(cfg.task, cfg.split),
            obs_mode="rgbd",
            cameras=(cfg.camera,),
            max_episode_steps=cfg.horizon,
            terminate_on_success=False,
        )
        self._env = trajectory.make_step_recorder(env, record_env_states=True)
        self.demos = cfg.demonstrations()

    def env(self, shard: RolloutShard | None = None) -> Any:
        return self._env

    def close(self) -> None:
        self._env.close()

    def source(self) -> dict[str, Any]:
        return {
            "source_type": "policy",
            "source_desc": (
                f"AED policy {self.cfg.policy} ({self.cfg.policy_sha256[:12]}), aed_eval.rollout"
            ),
        }

    def episode(
        self, shard: RolloutShard, k: int
    ) -> tuple[Any, trajectory.RecordedSteps, dict[str, Any]]:
        episode = self.rollout(shard, k)
        extra = {
            "role": ROLE,
            "policy": self.cfg.policy,
            "policy_sha256": self.cfg.policy_sha256,
            "labels_known": False,
            "index": k,
            "ending": self.cfg.ending,
            "success_step": first_step(episode.success),
            "fail_step": first_step(episode.fail),
        }
        return episode, self._env.take(), extra

    def rollout(self, shard: RolloutShard, k: int) -> Any:
        """One rollout: `horizon` steps, or (the paper's ending) until success or irrecoverable
        failure."""
        import torch

        from aed_tasks.episode import Episode

        seed = episode_seed(self.cfg.seed, shard.task, shard.split, shard.env_index, ROLE, k, 0)
        obs, _ = self._env.reset(seed=seed, options={"env_index": shard.env_index})
        with torch.no_grad():
            self.policy.reset(self.demos[shard.env_index])
            actions, success, fail, stage = [], [], [], []
            for _ in range(self.cfg.horizon):
                action = self.policy.act(obs)
                obs, _, _, _, info = self._env.step(
                    action
                )  # terminations ignored: success is latched
                actions.append(np.asarray(action, dtype=np.float32))
                success.append(_flag(info["success"]))
                fail.append(_flag(info["fail"]))
                stage.append(int(np.asarray(info["stage"]).reshape(-1)[0]))
                if self.cfg.ending == "success" and (success[-1] or fail[-1]):
                    break
        base = self._env.unwrapped
        return Episode(
            env_id=base.spec.id,
            task=shard.task,
            split=shard.split,
            env_index=base.env_index,
            seed=seed,
            demonstrator=False,
            control_mode=base.control_mode,
            actions=np.asarray(actions).reshape(-1, 4),
            success=np.asarray(success),
            fail=np.asarray(fail),
            stage=np.asarray(stage, dtype=np.int16),
            error_label=np.zeros(len(actions), dtype=np.uint8),
        )


def _flag(x: Any) -> bool:
    x = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
    return bool(x.reshape(-1)[0])


def first_step(flags: np.ndarray) -> int | None:
    """Index of the first step whose flag is set (None: never)."""
    hits = np.flatnonzero(np.asarray(flags, dtype=bool))
    return int(hits[0]) if len(hits) else None


def paper_ending(entry: dict[str, Any]) -> tuple[int, bool]:
    """(actions, succeeded) of a stored rollout under the paper's ending: it stops after its
    first success or irrecoverable-failure step, whichever comes first (never: the whole
    rollout)."""
    success, fail = entry.get("success_step"), entry.get("fail_step")
    ends = [step for step in (success, fail) if step is not None]
    actions = (
        min(int(entry["elapsed_steps"]), min(ends) + 1) if ends else int(entry["elapsed_steps"])
    )
    return actions, success is not None and (fail is None or success <= fail)


def run_rollouts(cfg: RolloutConfig) -> ProductionSummary:
    """Run every planned rollout shard that is not committed yet (resume = run again)."""
    cfg = cfg.with_checkpoint_hash()
    available = cfg.demonstrations().envs()
    if not available:
        raise FileNotFoundError(
            f"{cfg.demos}: no {cfg.split} demonstrations; collect them with "
            f"`aed collect --task {cfg.task} --split {cfg.split}`"
        )
    if cfg.split == "base" and not cfg.envs:
        available = [e for e in available if e not in policy_train_envs(Path(cfg.checkpoint))]
        if not available:
            raise ValueError(
                f"{cfg.demos}: every base environment with demonstrations trained the policy; "
                "collect more"
            )
    desc = f"rollout {cfg.policy} {cfg.task}-{cfg.split}"
    return produce(cfg, plan_shards(cfg, available), RolloutRunner, desc)


@dataclass
class StoredRollouts:
    """A policy's stored rollouts: their refs and json entries, how they ended, and their
    horizon."""

    refs: list[trajectory.EpisodeRef]
    entries: list[dict[str, Any]]
    horizon: int
    ending: str


def stored_rollouts(
    root: Path, policy: str, policy_sha256: str | None = None, hint: str = "`aed rollout`"
) -> StoredRollouts:
    """The rollouts of `policy` in `root`: one checkpoint (`policy_sha256` when given), one
    ending."""
    collection = trajectory.scan_collection(root)
    refs, entries, shas, endings, horizon = [], [], set(), set(), 0
    for shard in collection.shards:
        horizon = max(horizon, int(shard.body["env_info"].get("max_episode_steps") or 0))
        for entry, ref in zip(shard.body["episodes"], shard.episodes, strict=True):
            if ref.role != ROLE:
                continue
            if entry.get("policy") != policy:
                raise ValueError(
                    f"{shard.json_path}: rollouts of policy {entry.get('policy')!r}, not {policy!r}"
                )
            shas.add(entry.get("policy_sha256"))
            endings.add(
                entry.get("ending", "success")
            )  # rollouts recorded before endings stopped at success
            refs.append(ref)
            entries.append(entry)
    if not refs:
        raise ValueError(f"{root}: no rollouts of {policy}; run {hint} first")
    if len(shas) != 1 or len(endings) != 1:
        raise ValueError(
            f"{root}: rollouts of {len(shas)} policy checkpoints and {len(endings)} endings; "
            "keep one of each per folder"
        )
    sha = shas.pop()
    if policy_sha256 is not None and sha != policy_sha256:
        raise ValueError(
            f"{root}: rolled out by policy checkpoint {sha[:12]}, not the current "
            f"{policy_sha256[:12]}; re-run {hint}"
        )
    return StoredRollouts(refs, entries, horizon, endings.pop())


def policy_train_envs(checkpoint: Path) -> set[int]:
    """The base environments a policy checkpoint trained on."""
    from aed_eval.checks import trained_envs
    from aed_models.checkpoint import load_checkpoint
    from aed_models.policies import FAMILY

    return trained_envs(f"policy {checkpoint}", load_checkpoint(checkpoint, family=FAMILY).extra)[1]


# --- command -----------------------------------------------------------------------------------
def rollout(cfg: Annotated[RolloutConfig, tyro.conf.arg(name="")]) -> int:
    """Roll a trained policy out in a split's environments (resumes into --out)."""
    start = time.perf_counter()
    summary = run_rollouts(cfg)
    outcomes = [
        ref.success
        for ref in trajectory.scan_collection(summary.out).episodes()
        if ref.role == ROLE
    ]
    low, high = rate_interval(np.asarray(outcomes))
    print(
        f"{summary.out}: {summary.planned} shards ({summary.skipped} already there), "
        f"ran {summary.episodes} rollouts in {time.perf_counter() - start:.1f} s; "
        f"success rate {100 * np.mean(outcomes):.1f}% [{100 * low:.1f}, {100 * high:.1f}] "
        f"({sum(outcomes)}/{len(outcomes)}, {cfg.horizon} steps "
        f"each{', stopped at success' if cfg.ending == 'success' else ''})"
    )
    return 0

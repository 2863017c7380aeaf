"""One episode producer behind `aed collect` (the scripted expert) and `aed rollout` (a policy).

Work is cut into shards of one environment and a range of episode indices. A runner records a
shard's episodes with one actor into `<stem>.h5.tmp` and commits it atomically (see
`aed_tasks.trajectory`); the folder's manifest holds the settings it was made with. Seeds derive
from each episode's identity alone, so any number of workers (or Ray) records the same episodes,
and a killed run, re-run with the same arguments, redoes only the shards never committed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Protocol

from aed_eval.executors import execute
from aed_tasks import trajectory
from aed_tasks.episode import Episode
from aed_tasks.locks import folder_lock

logger = logging.getLogger(__name__)


class ShardPlan(Protocol):
    """A planned shard: its file stem, its episode indices and its json form."""

    @property
    def stem(self) -> str: ...

    def indices(self) -> range: ...

    def to_dict(self) -> dict[str, Any]: ...


@dataclass
class ShardResult:
    stem: str
    episodes: int
    steps: int
    successes: int
    attempts: int  # recorded episodes + rejected tries
    seconds: float


@dataclass
class ProductionSummary:
    out: Path
    planned: int  # shards
    skipped: int  # already committed
    results: list[ShardResult] = field(default_factory=list)

    @property
    def episodes(self) -> int:
        return sum(r.episodes for r in self.results)

    @property
    def successes(self) -> int:
        return sum(r.successes for r in self.results)

    @property
    def steps(self) -> int:
        return sum(r.steps for r in self.results)


class EpisodeRunner:
    """Records shards in one process. A subclass is the actor: `episode(shard, k)` gives one
    episode, what the recorder saw and the entry's extra json fields; `env(shard)` the env it ran
    in; `source()` what the shard's json says produced it."""

    def __init__(self, cfg: Any):
        self.cfg = cfg

    def env(self, shard: Any) -> Any:
        raise NotImplementedError

    def episode(
        self, shard: Any, k: int
    ) -> tuple[Episode, trajectory.RecordedSteps, dict[str, Any]]:
        raise NotImplementedError

    def source(self) -> dict[str, Any]:
        return {}

    def compression(self) -> trajectory.Compression:
        return trajectory.Compression()

    def close(self) -> None:
        pass

    def run(
        self, shard: Any, tick: Callable[[int], None] | None = None, out: Path | None = None
    ) -> ShardResult:
        """Record the shard's episodes into `<out>/<stem>.h5.tmp` (default: the config's), then
        commit it."""
        out = Path(out if out is not None else self.cfg.out)
        start = time.perf_counter()
        steps = successes = attempts = 0
        with trajectory.ShardWriter(out / f"{shard.stem}.h5", self.compression()) as writer:
            for k in shard.indices():
                episode, recorded, extra = self.episode(shard, k)
                writer.add(episode, recorded, **extra)
                steps += len(episode)
                successes += episode.succeeded
                attempts += int(extra.get("attempt", 0)) + 1
                if tick is not None:
                    tick(1)
            writer.commit(trajectory.env_info(self.env(shard)), shard.to_dict(), **self.source())
        episodes = len(shard.indices())
        return ShardResult(
            shard.stem, episodes, steps, successes, attempts, time.perf_counter() - start
        )


def check_plan(out: Path, shards: list[ShardPlan]) -> None:
    """Refuse an output that is a file, or a plan naming a shard twice (nothing is touched)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: a file, not a folder")
    stems = [s.stem for s in shards]
    repeated = sorted({stem for stem in stems if stems.count(stem) > 1})
    if repeated:
        raise ValueError(
            f"the plan names shards {repeated} more than once (an environment given twice?)"
        )


def prepare_folder(
    out: Path, identity: dict[str, Any], config: dict[str, Any], shards: list[ShardPlan]
) -> list[ShardPlan]:
    """Check the folder (manifest, every committed shard) and return the shards still to run.

    The caller holds the folder's lock (`produce` does). A corrupt or foreign file stops here
    with its name. A committed shard whose content differs from the plan (e.g. another shard
    size) is an error too, never overwritten.
    """
    out = Path(out)
    check_plan(out, shards)
    stems = [s.stem for s in shards]
    out.mkdir(parents=True, exist_ok=True)
    manifest = trajectory.read_manifest(out)
    if manifest is not None:
        old = manifest.get("identity", {})
        for key, value in identity.items():
            if old.get(key) != value:
                raise trajectory.CollectionError(
                    out / trajectory.MANIFEST,
                    f"was collected with {key}={old.get(key)!r}, this run asks {value!r}; "
                    "use another --out or the same setting",
                )
    collection = trajectory.scan_collection(
        out, check="full"
    )  # every shard, its sha256 too, before any write
    done = {s.json_path.stem: s for s in collection.shards}
    planned = set(stems)
    todo = []
    for shard in shards:
        info = done.get(shard.stem)
        if info is None:
            todo.append(shard)
        elif info.shard != shard.to_dict():
            raise trajectory.CollectionError(
                info.json_path,
                f"holds shard {info.shard}, this run plans {shard.to_dict()}; delete it or "
                "keep the earlier counts",
            )
    trajectory.write_json_atomic(
        out / trajectory.MANIFEST,
        {"format": trajectory.FORMAT, "identity": identity, "config": config},
    )
    for leftover in collection.temporaries + collection.uncommitted:
        stem = leftover.name.split(".")[0]
        if stem in planned:
            logger.info(
                "removing %s (left by an interrupted run; its shard is redone)", leftover.name
            )
            leftover.unlink()
    extra = sorted(set(done) - planned)
    if extra:
        logger.info("%d committed shard(s) in %s are outside this plan and kept", len(extra), out)
    return todo


def produce(
    cfg: Any,
    shards: list[ShardPlan],
    runner_type: type[EpisodeRunner],
    desc: str,
    on_done: Callable[[ShardResult], None] | None = None,
    runner: EpisodeRunner | None = None,
    runner_args: Iterable[Any] = (),
) -> ProductionSummary:
    """Record every planned shard of `cfg` (its out, identity, workers, executor) not committed yet.

    The output folder is locked for the whole run: a second run over it is refused with the
    first one's pid (`aed_tasks.locks`). `runner` (one worker only) reuses the envs of an
    earlier call; `runner_args` follow `cfg` in every new runner's constructor.
    """
    check_plan(Path(cfg.out), shards)
    with folder_lock(cfg.out):  # one writer per folder, from the first check to the last commit
        return _produce(cfg, shards, runner_type, desc, on_done, runner, runner_args)


def _produce(
    cfg: Any,
    shards: list[ShardPlan],
    runner_type: type[EpisodeRunner],
    desc: str,
    on_done: Callable[[ShardResult], None] | None,
    runner: EpisodeRunner | None,
    runner_args: Iterable[Any],
) -> ProductionSummary:
    from tqdm.auto import tqdm

    todo = prepare_folder(Path(cfg.out), cfg.identity(), cfg.to_dict(), shards)
    summary = ProductionSummary(Path(cfg.out), len(shards), len(shards) - len(todo))
    total = sum(len(s.indices()) for s in todo)
    logger.info(
        "%s: %d shards planned, %d already committed, %d episodes to record in %s",
        desc,
        len(shards),
        summary.skipped,
        total,
        cfg.out,
    )

    def done(result: ShardResult) -> None:
        summary.results.append(result)
        if on_done is not None:
            on_done(result)

    with tqdm(
        total=total, unit="ep", desc=desc, disable=not cfg.progress, dynamic_ncols=True
    ) as bar:
        execute(
            todo,
            partial(runner_type, cfg, *runner_args),
            on_done=done,
            workers=cfg.workers,
            executor=cfg.executor,
            ray_address=cfg.ray_address,
            progress=bar,
            runner=runner,
        )
    return summary

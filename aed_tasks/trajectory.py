"""Episode records on disk: ManiSkill's trajectory format (HDF5 + JSON) with AED's extensions.

One *shard* is a pair `<stem>.h5` + `<stem>.json` laid out exactly as ManiSkill's
`RecordEpisode` writes them, so `python -m mani_skill.trajectory.replay_trajectory` and
ManiSkill's other tools read it:

- h5, group `traj_<i>` per episode: `actions` (T, 4) float32, `terminated`, `truncated`,
  `success`, `fail` (T,) bool, `rewards` (T,) float32, `env_states/...` (T + 1, D) and
  `obs/...` (T + 1, ...) with `obs/sensor_data/<camera>/rgb` uint8 and `.../depth` int16
  millimetres (gzip or lzf). AED adds `error_label` (T,) uint8 (1 from the intervention
  on) and `stage` (T,) int16.
- json: `env_info` (`env_id`, `env_kwargs`, `max_episode_steps`), `episodes` (one dict per
  traj: `episode_id`, `episode_seed`, `reset_kwargs`, `control_mode`, `elapsed_steps`,
  `success`, `fail`), to which AED adds `role`, `task`, `split`, `env_index`, `error_kind`,
  `error_onset`, `suboptimal` per episode and a top-level `aed` block (format, shard, size
  and sha256 of the h5).

`env_id` is written as `aed_tasks:AED-<Task>-<split>`: Gymnasium imports the module before
making the env, so ManiSkill's tools find our tasks without any plug-in.

Writing is atomic: both files go to `<name>.tmp` first and are renamed, the json last. The
json is the commit marker: an h5 without its json is an unfinished shard, never read.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from aed_tasks.episode import ROLES, Episode, frame_labels_from_onset, onset_frame
from aed_tasks.locks import LOCK_NAME, lock_holder, pid_alive

logger = logging.getLogger(__name__)

FORMAT = "aed-trajectory/1"
MANIFEST = "aed_collection.json"
TMP_SUFFIX = ".tmp"
ENV_ID_MODULE = "aed_tasks"
IMAGE_KEYS = ("rgb", "depth", "seg", "segmentation")
EPISODE_KEYS = (
    "episode_id",
    "episode_seed",
    "reset_kwargs",
    "elapsed_steps",
    "role",
    "env_index",
    "split",
)
Check = Literal["size", "quick", "full"]
"""How much of a shard `read_shard` verifies. size: the json, the h5's recorded size and every
episode's groups. quick (the readers' default): also the h5's sha256, computed once per process
and file version (path, inode, size, mtime), so that damage of the same size is named before it
is read. full: the sha256 computed again on every read (before a collection is written to)."""


class CollectionError(RuntimeError):
    """A file of a collection folder is corrupt, foreign or inconsistent (the message names it)."""

    def __init__(self, path: Path | str, reason: str):
        self.path = Path(path)
        super().__init__(f"{self.path}: {reason}")


# --- recording ---------------------------------------------------------------------------------
Tree = dict[str, Any] | np.ndarray


def tree_map(fn: Callable[[Any], Any], tree: Any) -> Any:
    return {k: tree_map(fn, v) for k, v in tree.items()} if isinstance(tree, dict) else fn(tree)


def tree_stack(trees: list[Any]) -> Any:
    """Stack a list of equally shaped nested dicts of arrays along a new first axis."""
    if isinstance(trees[0], dict):
        return {k: tree_stack([t[k] for t in trees]) for k in trees[0]}
    return np.stack(trees)


def _first(x: Any) -> np.ndarray:
    """Drop ManiSkill's batch dimension (one env per process)."""
    x = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
    return x[0] if x.ndim > 0 else x


@dataclass
class RecordedSteps:
    """What `RecordEpisode` would keep of one episode: T + 1 observations and env states."""

    obs: Tree
    env_states: Tree | None
    terminated: np.ndarray  # (T,) bool
    truncated: np.ndarray  # (T,) bool
    rewards: np.ndarray  # (T,) float32
    reset_kwargs: dict[str, Any]

    @property
    def num_steps(self) -> int:
        return len(self.terminated)


def make_step_recorder(env: Any, record_env_states: bool = True) -> Any:
    """Wrap `env` so that its current episode is kept in memory (see `StepRecorder`)."""
    import gymnasium as gym

    class StepRecorder(gym.Wrapper):
        """Keeps obs, env states, flags and rewards of the current episode, writes nothing.

        `RecordEpisode` appends to its buffers with a copy per step and dumps its json after
        every episode; we need neither, and we need to add AED's fields before writing.
        """

        def __init__(self, env: Any):
            super().__init__(env)
            self.record_env_states = record_env_states
            self._clear()

        def _clear(self) -> None:
            self.obs: list[Any] = []
            self.states: list[Any] = []
            self.flags: list[tuple[bool, bool, float]] = []
            self.reset_kwargs: dict[str, Any] = {}

        def _keep(self, obs: Any) -> None:
            self.obs.append(tree_map(_first, obs))
            if self.record_env_states:
                self.states.append(tree_map(_first, self.env.unwrapped.get_state_dict()))

        def reset(self, *, seed: int | None = None, options: dict | None = None):
            obs, info = self.env.reset(seed=seed, options=options)
            self._clear()
            self.reset_kwargs = {"seed": seed, "options": dict(options or {})}
            self._keep(obs)
            return obs, info

        def step(self, action: Any):
            obs, reward, terminated, truncated, info = self.env.step(action)
            self._keep(obs)
            self.flags.append(
                (bool(_first(terminated)), bool(_first(truncated)), float(_first(reward)))
            )
            return obs, reward, terminated, truncated, info

        def take(self) -> RecordedSteps:
            """The episode so far (the buffers are handed over, not copied)."""
            flags = np.asarray(self.flags, dtype=np.float64).reshape(-1, 3)
            steps = RecordedSteps(
                obs=tree_stack(self.obs),
                env_states=tree_stack(self.states) if self.states else None,
                terminated=flags[:, 0].astype(bool),
                truncated=flags[:, 1].astype(bool),
                rewards=flags[:, 2].astype(np.float32),
                reset_kwargs=self.reset_kwargs,
            )
            self._clear()
            return steps

    return StepRecorder(env)


def env_info(env: Any) -> dict[str, Any]:
    """`env_info` of ManiSkill's json: what `gym.make` needs to rebuild the env."""
    from mani_skill.utils import gym_utils

    spec = env.unwrapped.spec
    if spec is None:
        raise ValueError("env was not made with gym.make: its env_id and kwargs are unknown")
    kwargs = json.loads(json.dumps(dict(spec.kwargs), default=_jsonable))
    return {
        "env_id": f"{ENV_ID_MODULE}:{spec.id}",
        "env_kwargs": kwargs,
        "max_episode_steps": gym_utils.find_max_episode_steps_value(env),
    }


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, (tuple, set, np.ndarray)):
        return list(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def plain_env_id(env_id: str) -> str:
    """`aed_tasks:AED-PickPlace-base` -> `AED-PickPlace-base`."""
    return env_id.split(":", 1)[-1]


# --- writing -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Compression:
    """HDF5 filter of the image datasets: gzip (level 0-9, smaller) or lzf (faster)."""

    method: Literal["gzip", "lzf"] = "gzip"
    level: int = 4

    def kwargs(self) -> dict[str, Any]:
        if self.method == "lzf":
            return {"compression": "lzf"}
        return {"compression": "gzip", "compression_opts": self.level}


def _add_tree(group: Any, key: str, data: Tree, compression: Compression) -> None:
    """Nested dicts become groups, arrays datasets; images are compressed frame-chunked."""
    if isinstance(data, dict):
        sub = group.create_group(key, track_order=True)
        for k, v in data.items():
            _add_tree(sub, k, v, compression)
    elif key in IMAGE_KEYS and data.ndim >= 3:
        group.create_dataset(key, data=data, chunks=(1, *data.shape[1:]), **compression.kwargs())
    else:
        group.create_dataset(key, data=data)


def episode_entry(
    episode_id: int, episode: Episode, steps: RecordedSteps, **extra: Any
) -> dict[str, Any]:
    """ManiSkill's episode dict plus AED's fields."""
    seed = steps.reset_kwargs.get("seed", episode.seed)
    return {
        "episode_id": episode_id,
        "episode_seed": int(seed),
        "reset_kwargs": json.loads(json.dumps(steps.reset_kwargs, default=_jsonable)),
        "control_mode": episode.control_mode,
        "elapsed_steps": len(episode),
        "success": episode.succeeded,
        "fail": episode.failed_irrecoverably,
        "role": episode.role,
        "task": episode.task,
        "split": episode.split,
        "env_index": int(episode.env_index),
        "error_kind": episode.error_kind,
        "error_onset": None if episode.error_onset is None else int(episode.error_onset),
        "suboptimal": bool(episode.suboptimal),
        "demonstrator": bool(episode.demonstrator),
        "expert_speed": float(episode.expert_speed),
        **extra,
    }


def _check_lengths(episode: Episode, steps: RecordedSteps) -> None:
    if steps.num_steps != len(episode):
        raise ValueError(
            f"recorded {steps.num_steps} steps but the episode has {len(episode)} actions"
        )


class ShardWriter:
    """Streams episodes into `<stem>.h5.tmp`; `commit()` renames it and writes the json marker.

    Episodes are written as they arrive, so a shard never holds more than one episode's
    frames in memory. Nothing is visible under the final names before `commit()`.
    """

    def __init__(self, h5_path: Path, compression: Compression = Compression()):
        import h5py

        self.h5_path = Path(h5_path)
        self.json_path = self.h5_path.with_suffix(".json")
        self.tmp_h5 = self.h5_path.with_name(self.h5_path.name + TMP_SUFFIX)
        self.compression = compression
        self.episodes: list[dict[str, Any]] = []
        self.h5_path.parent.mkdir(parents=True, exist_ok=True)
        self._h5 = h5py.File(self.tmp_h5, "w", track_order=True)

    def add(self, episode: Episode, steps: RecordedSteps, **extra: Any) -> dict[str, Any]:
        _check_lengths(episode, steps)
        episode_id = len(self.episodes)
        group = self._h5.create_group(f"traj_{episode_id}", track_order=True)
        _add_tree(group, "obs", steps.obs, self.compression)
        group.create_dataset("actions", data=episode.actions.astype(np.float32))
        group.create_dataset("terminated", data=steps.terminated.astype(bool))
        group.create_dataset("truncated", data=steps.truncated.astype(bool))
        group.create_dataset("success", data=episode.success.astype(bool))
        group.create_dataset("fail", data=episode.fail.astype(bool))
        if steps.env_states is not None:
            _add_tree(group, "env_states", steps.env_states, self.compression)
        group.create_dataset("rewards", data=steps.rewards.astype(np.float32))
        group.create_dataset("error_label", data=episode.error_label.astype(np.uint8))
        group.create_dataset("stage", data=episode.stage.astype(np.int16))
        entry = episode_entry(episode_id, episode, steps, **extra)
        self.episodes.append(entry)
        return entry

    def commit(self, info: dict[str, Any], shard: dict[str, Any] | None = None, **top: Any) -> None:
        """Close the h5, rename it into place, then write the json (the commit marker)."""
        self._h5.close()
        _fsync(self.tmp_h5)
        os.replace(self.tmp_h5, self.h5_path)
        body = {
            "env_info": info,
            "source_type": "motionplanning",
            "source_desc": "AED scripted expert (mplib), aed_eval.collect",
            **top,
            "aed": {
                "format": FORMAT,
                "shard": shard or {},
                "h5_bytes": self.h5_path.stat().st_size,
                "h5_sha256": _hash_verified(self.h5_path),
            },
            "episodes": self.episodes,
        }
        write_json_atomic(self.json_path, body)

    def abort(self) -> None:
        """Drop the unfinished shard (its temporary file)."""
        try:
            self._h5.close()
        finally:
            self.tmp_h5.unlink(missing_ok=True)

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type: Any, *_: Any) -> None:
        if exc_type is not None:
            self.abort()


def write_json_atomic(path: Path, body: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + TMP_SUFFIX)
    with open(tmp, "w") as f:
        json.dump(body, f, indent=2, default=_jsonable)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def write_npz_atomic(path: Path, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """`np.savez` of `arrays` and a JSON `meta` to a temporary file, fsync, rename over `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}{TMP_SUFFIX}")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: Path) -> None:
    try:
        _fsync(path)
    except OSError:  # some filesystems refuse fsync on directories
        pass


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# (path, device, inode, size, mtime_ns) of each h5 whose sha256 this process verified -> sha256
_VERIFIED: dict[tuple[str, int, int, int, int], str] = {}


def _version(path: Path) -> tuple[str, int, int, int, int]:
    stat = path.stat()
    return (str(path.resolve()), stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


def _hash_verified(path: Path) -> str:
    """The sha256 of a file this process just wrote, remembered as verified."""
    digest = sha256(path)
    _VERIFIED[_version(path)] = digest
    return digest


# --- reading -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeRef:
    """Where one episode lives and what it is, from the json alone (no frames read)."""

    path: Path  # the .h5
    traj: str  # "traj_<i>"
    role: str
    task: str
    split: str
    env_index: int
    length: int  # T actions; T + 1 frames
    seed: int
    success: bool
    error_kind: str | None = None
    error_onset: int | None = None
    suboptimal: bool = False

    @property
    def num_frames(self) -> int:
        return self.length + 1

    @property
    def onset_frame(self) -> int | None:
        return onset_frame(self.error_onset)

    def frame_labels(self) -> np.ndarray:
        """(T + 1,) bool: which frames follow the error's onset."""
        return frame_labels_from_onset(self.num_frames, self.error_onset)


@dataclass
class ShardInfo:
    json_path: Path
    h5_path: Path
    body: dict[str, Any]
    episodes: list[EpisodeRef]

    @property
    def shard(self) -> dict[str, Any]:
        return self.body["aed"].get("shard", {})

    @property
    def num_bytes(self) -> int:
        return self.h5_path.stat().st_size + self.json_path.stat().st_size


@dataclass
class Collection:
    """A scanned folder: committed shards, plus leftovers of interrupted runs."""

    root: Path
    shards: list[ShardInfo] = field(default_factory=list)
    temporaries: list[Path] = field(default_factory=list)  # *.tmp of an interrupted writer
    uncommitted: list[Path] = field(default_factory=list)  # .h5 renamed, json not yet written

    def episodes(self) -> list[EpisodeRef]:
        return [e for s in self.shards for e in s.episodes]

    def __iter__(self) -> Iterator[ShardInfo]:
        return iter(self.shards)


def verify_sha256(h5_path: Path, expected: Any, cached: bool = True) -> None:
    """Raise `CollectionError` when the h5's sha256 is not `expected` (the one its json recorded).

    `cached`: a file version already verified in this process is not hashed again; any write
    changes its size or mtime (or inode, when replaced), and so its key.
    """
    key = _version(h5_path)
    if cached and expected is not None and _VERIFIED.get(key) == expected:
        return
    digest = sha256(h5_path)
    if digest != expected:
        raise CollectionError(
            h5_path,
            "corrupt: sha256 differs from the one its json recorded (damaged after it was "
            "written); delete this shard's .json and .h5 and re-run",
        )
    _VERIFIED[key] = digest


def read_shard(json_path: Path, check: Check = "quick") -> ShardInfo:
    """Read and validate one committed shard; any problem raises `CollectionError` naming the file.

    size: json well-formed, h5 present with the recorded size, every traj group present with
    consistent lengths. quick: also the h5's sha256, once per process and file version. full:
    the sha256 on every call (see `Check`).
    """
    import h5py

    if check not in ("size", "quick", "full"):
        raise ValueError(f"check={check!r}: size, quick or full")
    json_path = Path(json_path)
    h5_path = json_path.with_suffix(".h5")
    try:
        body = json.loads(json_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CollectionError(
            json_path, f"corrupt json ({e}); delete this shard's .json and .h5 and re-run"
        ) from e
    aed = body.get("aed") if isinstance(body, dict) else None
    if not isinstance(aed, dict) or aed.get("format") != FORMAT:
        raise CollectionError(
            json_path, f"not an AED trajectory json (no aed.format == {FORMAT!r})"
        )
    if not h5_path.exists():
        raise CollectionError(json_path, f"its h5 {h5_path.name} is missing")
    size = h5_path.stat().st_size
    if size != aed.get("h5_bytes"):
        raise CollectionError(
            h5_path, f"corrupt: {size} bytes, its json recorded {aed.get('h5_bytes')}"
        )
    if check != "size":
        verify_sha256(h5_path, aed.get("h5_sha256"), cached=check == "quick")
    episodes = body.get("episodes")
    if not isinstance(episodes, list) or not isinstance(body.get("env_info"), dict):
        raise CollectionError(json_path, "corrupt json: no env_info or episodes list")
    refs = []
    try:
        with h5py.File(h5_path, "r") as h5:
            for entry in episodes:
                refs.append(_episode_ref(h5_path, h5, entry))
    except CollectionError:
        raise
    except Exception as e:  # h5py raises OSError/KeyError/ValueError variously on damage
        raise CollectionError(h5_path, f"corrupt h5 ({type(e).__name__}: {e})") from e
    return ShardInfo(json_path, h5_path, body, refs)


def _episode_ref(h5_path: Path, h5: Any, entry: Any) -> EpisodeRef:
    missing = [k for k in EPISODE_KEYS if not isinstance(entry, dict) or k not in entry]
    if missing:
        raise CollectionError(h5_path.with_suffix(".json"), f"episode entry lacks {missing}")
    traj = f"traj_{entry['episode_id']}"
    if traj not in h5:
        raise CollectionError(h5_path, f"group {traj} is missing")
    steps = int(entry["elapsed_steps"])
    group = h5[traj]
    for key in ("actions", "error_label"):
        if key not in group or len(group[key]) != steps:
            raise CollectionError(h5_path, f"{traj}/{key} is missing or not {steps} long")
    if entry["role"] not in ROLES:
        raise CollectionError(
            h5_path.with_suffix(".json"), f"{traj}: unknown role {entry['role']!r}"
        )
    return EpisodeRef(
        path=h5_path,
        traj=traj,
        role=entry["role"],
        task=entry.get("task", ""),
        split=entry["split"],
        env_index=int(entry["env_index"]),
        length=steps,
        seed=int(entry["episode_seed"]),
        success=bool(entry.get("success", False)),
        error_kind=entry.get("error_kind"),
        error_onset=entry.get("error_onset"),
        suboptimal=bool(entry.get("suboptimal", False)),
    )


def scan_collection(root: Path, check: Check = "quick") -> Collection:
    """Every shard of `root` (non-recursive), validated. Foreign files raise `CollectionError`.

    Known leftovers of an interrupted writer (`*.tmp`, an `.h5` whose json was never
    written) are listed in the result and logged, not treated as data.
    """
    root = Path(root)
    if not root.is_dir():
        raise CollectionError(root, "no such collection folder")
    collection = Collection(root)
    names = {p.name for p in root.iterdir()}
    for name in sorted(names):
        path = root / name
        if name in (MANIFEST, LOCK_NAME):
            continue
        if name.endswith(TMP_SUFFIX) and name[: -len(TMP_SUFFIX)].endswith((".h5", ".json")):
            collection.temporaries.append(path)
        elif name.endswith(".json") and path.is_file():
            collection.shards.append(read_shard(path, check))
        elif name.endswith(".h5") and path.is_file():
            if name[:-3] + ".json" not in names:
                collection.uncommitted.append(path)
        else:
            raise CollectionError(
                path,
                "foreign file in a collection folder (only <shard>.h5/.json, "
                f"{MANIFEST} and {LOCK_NAME} belong here); move it elsewhere",
            )
    leftovers = collection.temporaries + collection.uncommitted
    holder = lock_holder(root)  # another live writer's temporaries are no leftovers
    if leftovers and holder not in (None, os.getpid()) and pid_alive(holder):
        logger.info(
            "%s: being written by pid %d: %d unfinished shard(s) not read",
            root,
            holder,
            len(leftovers),
        )
    elif leftovers:
        logger.warning(
            "%s: %d leftover(s) of an interrupted collection, not read: %s",
            root,
            len(leftovers),
            ", ".join(p.name for p in leftovers),
        )
    return collection


# --- frames ------------------------------------------------------------------------------------
def read_frames(h5: Any, traj: str, camera: str = "front") -> tuple[np.ndarray, np.ndarray]:
    """(T + 1, H, W, 3) uint8 RGB and (T + 1, H, W, 1) int16 depth (mm) of one camera."""
    data = h5[f"{traj}/obs/sensor_data/{camera}"]
    return data["rgb"][()], data["depth"][()]


def read_manifest(root: Path) -> dict[str, Any] | None:
    path = Path(root) / MANIFEST
    if not path.exists():
        return None
    try:
        body = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise CollectionError(path, f"corrupt manifest ({e})") from e
    if not isinstance(body, dict):
        raise CollectionError(path, "corrupt manifest (not a JSON object)")
    return body

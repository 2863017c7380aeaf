"""The `aed` command line: one console script, one subcommand per protocol step."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

logger = logging.getLogger("aed")


def _commands() -> dict[str, Callable[..., Any]]:
    from aed_eval import (
        calibrate,
        collect,
        data_info,
        demo,
        doctor,
        evaluate,
        experiments,
        models,
        monitor,
        render,
        report,
        results,
        rollout,
        train,
    )

    return {
        "doctor": doctor.doctor,
        "envs": doctor.list_envs,
        "render": render.render_envs,
        "collect": collect.collect,
        "data-info": data_info.data_info,
        "train-encoder": train.train_encoder,
        "train-localizer": train.train_localizer,
        "train-policy": train.train_policy,
        "train-detector": train.train_detector,
        "rollout": rollout.rollout,
        "calibrate": calibrate.calibrate,
        "evaluate": evaluate.evaluate,
        "monitor": monitor.monitor,
        "report": report.report,
        "models": models.models,
        "demo": demo.demo,
        "experiments": experiments.experiments,
        "results": results.results,
    }


def _preset_commands() -> dict[str, tuple[Callable[..., Any], tuple[str, ...], Callable[..., Any]]]:
    """Commands whose config is built from a named preset: (the preset's builder, the flags
    that choose it, the command). Their `--help` shows the chosen preset's values."""
    from aed_eval import collect, demo, rollout, train

    return {
        "collect": (
            collect.CollectConfig.from_preset,
            ("task", "split", "profile"),
            collect.collect,
        ),
        "train-encoder": (train.encoder_preset, ("task", "profile"), train.train_encoder),
        "train-localizer": (
            train.localizer_preset,
            ("task", "profile"),
            train.train_localizer,
        ),
        "train-policy": (train.policy_preset, ("task", "policy", "profile"), train.train_policy),
        "train-detector": (
            train.detector_preset,
            ("task", "detector", "profile", "policy"),
            train.train_detector,
        ),
        "rollout": (
            rollout.RolloutConfig.from_preset,
            ("task", "policy", "split", "profile"),
            rollout.rollout,
        ),
        "demo": (demo.DemoConfig.from_preset, ("task", "profile"), demo.demo),
    }


def parse_preset_command(name: str, argv: list[str]) -> Any:
    """The config of `aed <name> ...`: the preset named by its choosing flags (the command's
    defaults where absent) gives every other field its default, which the other flags override."""
    import argparse

    import tyro

    preset, keys, command = _preset_commands()[name]
    chooser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    for key in keys:
        chooser.add_argument(f"--{key}")
    chosen, rest = chooser.parse_known_args(argv)  # the preset holds the chosen values already
    default = preset(**{k: v for k, v in vars(chosen).items() if v is not None})
    return tyro.cli(
        type(default), default=default, args=rest, prog=f"aed {name}", description=command.__doc__
    )


class ConfigRejected(ValueError):
    """A config's own validation refused the parsed flags (its message names the problem)."""


@contextmanager
def one_line_config_errors() -> Iterator[None]:
    """tyro draws a box around a config's validation error; raise it as one line instead.

    Uses tyro's parse-error hook where this tyro has it (1.0.17 does); else tyro's box stays.
    """
    import tyro

    register = getattr(getattr(tyro, "_errors", None), "on_parse_error", None)
    if register is None:
        yield
        return

    def hook(event: Any) -> None:
        if type(event).__name__ == "InstantiationFailure" and getattr(event, "message", None):
            raise ConfigRejected(event.message)

    with register(hook):
        yield


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `aed` console script.

    Bad input (an unknown task, a wrong value, a corrupt or foreign file) ends with one line
    naming the problem and exit status 2; `AED_DEBUG=1` shows the traceback instead.
    """
    import tyro

    from aed_eval.logs import setup_logging
    from aed_tasks.locks import FolderLockedError
    from aed_tasks.trajectory import CollectionError

    setup_logging()
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        if argv and argv[0] in _preset_commands():
            with one_line_config_errors():
                cfg = parse_preset_command(argv[0], argv[1:])
            result = _preset_commands()[argv[0]][2](cfg)
        else:
            with one_line_config_errors():
                result = tyro.extras.subcommand_cli_from_dict(_commands(), args=argv, prog="aed")
    except (
        ValueError,
        KeyError,
        IndexError,
        FileNotFoundError,
        CollectionError,
        FolderLockedError,
    ) as e:  # CheckpointError is a ValueError
        if os.environ.get("AED_DEBUG"):
            raise
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        logger.error("%s", message)
        return 2
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())

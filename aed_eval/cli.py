"""The `aed` command line: one console script, one subcommand per protocol step."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable
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
        models,
        monitor,
        render,
        report,
        rollout,
        train,
    )

    return {
        "doctor": doctor.doctor,
        "envs": doctor.list_envs,
        "render": render.render_envs,
        "collect": collect.collect,
        "data-info": data_info.data_info,
        "train-policy": train.train_policy,
        "train-detector": train.train_detector,
        "rollout": rollout.rollout,
        "calibrate": calibrate.calibrate,
        "evaluate": evaluate.evaluate,
        "monitor": monitor.monitor,
        "report": report.report,
        "models": models.models,
        "demo": demo.demo,
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `aed` console script.

    Bad input (an unknown task, a wrong value, a corrupt or foreign file) ends with one line
    naming the problem and exit status 2; `AED_DEBUG=1` shows the traceback instead.
    """
    import tyro

    from aed_eval.logs import setup_logging
    from aed_tasks.trajectory import CollectionError

    setup_logging()
    try:
        result = tyro.extras.subcommand_cli_from_dict(_commands(), args=argv, prog="aed")
    except (ValueError, KeyError, IndexError, FileNotFoundError, CollectionError) as e:  # CheckpointError is a ValueError
        if os.environ.get("AED_DEBUG"):
            raise
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        logger.error("%s", message)
        return 2
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())

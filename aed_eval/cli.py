"""The `aed` command line: one console script, one subcommand per protocol step."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import Any

logger = logging.getLogger("aed")


def _commands() -> dict[str, Callable[..., Any]]:
    from aed_eval import demo, doctor, render

    return {
        "doctor": doctor.doctor,
        "envs": doctor.list_envs,
        "render": render.render_envs,
        "demo": demo.demo,
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `aed` console script."""
    import tyro

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("mani_skill").setLevel(logging.ERROR)  # e.g. "no CUDA device" on CPU machines
    result = tyro.extras.subcommand_cli_from_dict(_commands(), args=argv, prog="aed")
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())

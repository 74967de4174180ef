"""One logging set-up for every entry point (the CLI, workers, simulators)."""

from __future__ import annotations

import argparse
import logging

LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


def add_log_level_argument(parser: argparse.ArgumentParser, default: str = "WARNING") -> None:
    parser.add_argument(
        "--log-level",
        default=default,
        choices=LEVELS,
        help="logging threshold on stderr (default: %(default)s)",
    )


def configure(level: str) -> None:
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")


def rate_limited(count: int) -> bool:
    """Whether the ``count``-th occurrence of a repeated problem is logged: the first ten, then
    every thousandth, so a flood of bad input from the network cannot flood the log."""
    return count <= 10 or count % 1000 == 0

"""One logging set-up for every entry point (the CLI, workers, simulators), and the rate-limited
counting of problems with network input (issue 11: every rejection logged, counted, shown)."""

from __future__ import annotations

import argparse
import logging
from collections import Counter
from collections.abc import Callable
from typing import Any

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


def count_problem(
    counters: Counter[str],
    counter: str,
    logger: logging.Logger,
    message: str,
    *details: Any,
    exc_info: bool = False,
) -> None:
    """Count one more ``counter`` (a rejection, a sample consumed without an output) and log
    ``message % details`` if :func:`rate_limited` lets it through."""
    counters[counter] += 1
    if rate_limited(counters[counter]):
        logger.warning(message, *details, exc_info=exc_info)


def guarded(
    handler: Callable[..., None], counters: Counter[str], logger: logging.Logger, where: str
) -> Callable[..., None]:
    """``handler`` made total, for zenoh callbacks and the handlers of network input: an
    unexpected exception is counted (``internal_errors``) and logged with its traceback
    (rate-limited), never raised into zenoh's thread or the caller's loop."""

    def run(*arguments: Any) -> None:
        try:
            handler(*arguments)
        except Exception:
            count_problem(
                counters, "internal_errors", logger, "%s: internal error", where, exc_info=True
            )

    return run

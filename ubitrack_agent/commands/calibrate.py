"""``ubitrack calibrate``: calibrate a static relation live, watch it converge, keep it.

Asks the agent for FROM->TO as a static relation. When it is computed over time from dynamic
inputs (the paper's section 4.2), the worker reports its progress
(``ubitrack_agent.net.progress``) and this command shows it as it goes: samples used and
rejected, the current uncertainty against the tolerances (a bar towards convergence), the
spread of the samples, and what to do. It ends when the estimate has converged, printing the
result and its uncertainty, and with ``--save`` sends it to the calibration store (``ubitrack
store``), which writes it to its file and serves it from then on. A relation that is already
a measured static edge (stored earlier) is printed as it is.

Exit status: 0 converged (and saved with ``--save``) or already known; 1 not static, no
convergence within ``--timeout``, or the store refused or did not answer; 2 bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

from ubitrack_agent.net import config

TYPES = ("6D", "3D", "3R")
KNOWN_WAIT_S = 2.0
"""A value that has arrived while no progress report came for this long is not being
calibrated: it is a measured static edge (a stored calibration)."""
PRINT_EVERY_S = 0.5
"""Progress lines at most this often (a report comes with every sample), and on each change
of status."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        help="calibrate a static relation live, showing its progress; --save keeps it",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", metavar="FROM", help="source frame, e.g. C")
    parser.add_argument("target", metavar="TO", help="target frame, e.g. HT")
    parser.add_argument("--type", default="6D", choices=TYPES, help="(default: %(default)s)")
    parser.add_argument(
        "--save", action="store_true", help="send the converged result to the calibration store"
    )
    parser.add_argument("--store", default="store", help="store name (default: %(default)s)")
    parser.add_argument(
        "--timeout",
        type=float,
        default=300.0,
        help="give up after this many seconds without convergence (default: %(default)s)",
    )
    parser.add_argument(
        "--json", action="store_true", help="one JSON object per progress report and result"
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def _bar(fraction: float, width: int = 20) -> str:
    filled = round(max(0.0, min(1.0, fraction)) * width)
    return "[" + "#" * filled + "-" * (width - filled) + f"] {fraction * 100:3.0f}%"


def _mm(metres: float | None) -> str:
    return "-" if metres is None else f"{metres * 1000:.2f} mm"


def _deg(radians: float | None) -> str:
    return "-" if radians is None else f"{math.degrees(radians):.3f} deg"


def advice(progress: Any, source: str, target: str) -> str:
    """What the person calibrating should do now."""
    seen = progress.accepted + progress.rejected
    if progress.status == "initialising":
        return f"collecting the first samples: keep {source} and {target} measured"
    if seen and progress.rejected > 0.2 * seen:
        return "many samples rejected: check for occlusions, reflections or a loose target"
    if progress.status == "converged":
        return "converged"
    return f"keep {source} and {target} measured and move them slowly through varied views"


def describe(progress: Any, source: str, target: str) -> str:
    """One line of progress for people."""
    return (
        f"{_bar(progress.fraction_done())} {progress.status}: {progress.accepted} samples, "
        f"{progress.rejected} rejected; uncertainty {_mm(progress.std_translation)} "
        f"{_deg(progress.std_rotation)} (target {_mm(progress.tolerance_translation)} "
        f"{_deg(progress.tolerance_rotation)}); spread {_mm(progress.spread_translation)} "
        f"{_deg(progress.spread_rotation)}. {advice(progress, source, target)}"
    )


def _waited(since: float | None, seconds: float) -> bool:
    return since is not None and time.monotonic() - since > seconds


def _save(session: Any, keys: Any, store: str, request: dict[str, Any]) -> dict[str, Any]:
    """Send a save request to the store; its answer, or ``RuntimeError`` saying why not."""
    replies = list(session.get(keys.store(store), payload=json.dumps(request), timeout=5.0))
    for reply in replies:
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
        raise RuntimeError(f"the store refused: {reply.err.payload.to_bytes().decode()}")
    raise RuntimeError(
        f"no calibration store answers on {keys.store(store)}; start one with `ubitrack store FILE`"
    )


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.core import to_json
    from ubitrack_agent.io.application import NotStatic, Relation
    from ubitrack_agent.net.keys import KeySpace, RelationId
    from ubitrack_agent.net.session import open_session

    prog = "ubitrack calibrate"
    try:
        settings = config.from_arguments(args, role="member")
        relation_id = RelationId(args.source, args.target, args.type, static=True)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2

    def say(document: dict[str, Any], text: str) -> None:
        print(json.dumps(document) if args.json else text, flush=True)

    keys = KeySpace(settings.key_prefix)
    with (
        open_session(settings) as session,
        Relation(session, keys, relation_id, application=None) as relation,
    ):
        deadline = time.monotonic() + args.timeout
        shown, first_value_at, printed_at = None, None, 0.0
        progress = None
        while time.monotonic() < deadline:
            try:
                relation.wait_for(timeout=0.5)
            except TimeoutError:
                pass
            except NotStatic as exc:
                say({"event": "not_static", **vars(exc.progress)}, f"{prog}: {exc}")
                return 1
            progress = relation.progress
            if relation.latest() is not None and first_value_at is None:
                first_value_at = time.monotonic()
            due = time.monotonic() - printed_at > PRINT_EVERY_S
            if (
                progress is not None
                and not _waited(relation.progress_at, KNOWN_WAIT_S)
                and (progress.status != shown or due)
            ):
                shown, printed_at = progress.status, time.monotonic()
                line = describe(progress, relation_id.source, relation_id.target)
                say({"event": "progress", **vars(progress)}, line)
                if progress.converged:
                    break
            elif _waited(first_value_at, KNOWN_WAIT_S) and (
                progress is None or _waited(relation.progress_at, KNOWN_WAIT_S)
            ):
                value = to_json(relation.latest())
                say(
                    {"event": "known", "value": value},
                    f"{relation_id} is already known (a measured static edge): {value}",
                )
                return 0
        else:
            print(
                f"{prog}: {relation_id} did not converge within {args.timeout:.0f} s",
                file=sys.stderr,
            )
            return 1
        result = {"event": "converged", "value": progress.value, "instance": progress.instance}
        say(
            result,
            f"converged: {relation_id} = {json.dumps(progress.value)}\n"
            f"  uncertainty {_mm(progress.std_translation)} {_deg(progress.std_rotation)} "
            f"from {progress.accepted} samples ({progress.rejected} rejected)",
        )
        if not args.save:
            return 0
        value = {k: v for k, v in progress.value.items() if k not in ("type", "timestamp_ns")}
        request = {
            "from": relation_id.source,
            "to": relation_id.target,
            "type": relation_id.type,
            "value": value,
            "provenance": {
                "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "flow": progress.instance,
                "samples": progress.accepted,
                "rejected": progress.rejected,
                "std_translation": progress.std_translation,
                "std_rotation": progress.std_rotation,
            },
        }
        try:
            answer = _save(session, keys, args.store, request)
        except RuntimeError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 1
        say({"event": "saved", **answer}, f"saved as {answer['edge']} in {answer['file']}")
    return 0

"""``ubitrack calibrate``: calibrate a static relation live, watch it converge, keep it.

Asks the agent for FROM->TO as a static relation. When it is computed over time from dynamic
inputs (the paper's section 4.2), the worker reports its progress
(``ubitrack_agent.net.progress``) and this command shows it as it goes: samples used and
rejected, the current uncertainty against the tolerances (a bar towards convergence), the
spread of the samples, and what to do. It ends when the estimate has converged, printing the
result and its uncertainty, and with ``--save`` sends it to the calibration store (``ubitrack
store``), which writes it to its file and serves it from then on. A relation that is already
a measured static edge (stored earlier) is printed as it is.

With ``--recalibrate`` it calibrates the relation again, as after remounting a target: the
agent computes it from the dynamic inputs while ignoring the measured static edges between the
two frames (the stored value, in either direction), on keys of its own, so the applications
using the stored value are not disturbed meanwhile. ``--save`` then replaces the stored value
(the store keeps the previous one in the entry's history), and from then on the static relation
and every tracking flow use the new one.

The agent's answer comes at once: if it cannot serve the relation, its reason (``ubitrack
status`` lists the same) and exit 1, with a "did you mean" for a frame named almost like an
announced one; while the flow computing it starts, a line as it comes up ("planned: 3
components, 1 alive"), then the progress; if no agent is there within 1.5 s, "no agent on
ENDPOINT/DOMAIN" and exit 1. ``--wait`` waits on instead (up to ``--timeout``), for sensors or
an agent still starting.

Exit status: 0 converged (and saved with ``--save``) or already known; 1 the agent cannot serve
the relation, no agent, not static, no convergence within ``--timeout``, or the store refused
or did not answer; 2 bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.net import config

TYPES = ("6D", "3D", "3R")


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
        "--recalibrate",
        action="store_true",
        help="calibrate again, ignoring the stored value (and any measured static edge) of the "
        "relation",
    )
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
        "--wait",
        action="store_true",
        help="keep waiting (up to --timeout) when the agent cannot serve the relation yet or "
        "no agent is there yet, instead of exiting 1 at once",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per line: planned, progress, result (and the reason it ends "
        "without one)",
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


def _known_from(recalibrate: bool) -> str:
    """Where a value that needs no calibrating comes from."""
    if recalibrate:
        return "computed from other static edges, without calibrating"
    return "a measured static edge"


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.commands.subscribe import no_agent
    from ubitrack_agent.io.application import NoAgent, NotStatic, Relation, UnsolvedRelation
    from ubitrack_agent.io.calibration import StoreError, follow, save, save_request
    from ubitrack_agent.io.waiting import StartWatch, network_of
    from ubitrack_agent.net.keys import KeySpace, RelationId
    from ubitrack_agent.net.progress import Progress
    from ubitrack_agent.net.session import open_session

    prog = "ubitrack calibrate"
    try:
        settings = config.from_arguments(args, role="member")
        relation_id = RelationId(
            args.source, args.target, args.type, static=True, recalibrate=args.recalibrate
        )
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2

    def say(document: dict[str, Any], text: str) -> None:
        write_line(json.dumps(document) if args.json else text)

    def fail(document: dict[str, Any], message: str) -> int:
        """Say why it ends without a result (stderr; with --json also as a line on stdout)."""
        if args.json:
            write_line(json.dumps({**document, "message": message}))
        print(f"{prog}: {message}", file=sys.stderr)
        return 1

    keys = KeySpace(settings.key_prefix)

    def planned(line: str) -> None:
        say({"event": "planned", "line": line}, f"{relation_id}: {line}")

    with (
        open_session(settings) as session,
        StartWatch(session, keys, relation_id, planned) as watch,
        Relation(
            session, keys, relation_id, host=settings.host_name, keep_waiting=args.wait
        ) as relation,
    ):

        def report(progress: Progress) -> None:
            watch.close()  # the flow is up
            line = describe(progress, relation_id.source, relation_id.target)
            say({"event": "progress", **vars(progress)}, line)

        try:
            outcome = follow(relation, args.timeout, report)
        except UnsolvedRelation as exc:  # the reason ends with a "did you mean", if one fits
            return fail({"event": "unsolved", "reason": exc.reason}, str(exc))
        except NoAgent as exc:
            message = f"{relation_id}: {no_agent(network_of(settings), exc.timeout, args.wait)}"
            return fail({"event": "no_agent", "message": message}, message)
        watch.close()
        if outcome.kind == "known":
            say(
                {"event": "known", "value": outcome.value},
                f"{relation_id} is already known ({_known_from(args.recalibrate)}): "
                f"{outcome.value}",
            )
            return 0
        if outcome.kind == "not_static":
            message = f"{prog}: {NotStatic(relation_id, outcome.progress)}"
            say({"event": "not_static", "message": message, **vars(outcome.progress)}, message)
            return 1
        if outcome.kind == "timeout":
            silence = relation.silence(args.timeout)
            cause = getattr(silence, "cause", None)
            print(
                f"{prog}: {relation_id} did not converge within {args.timeout:.0f} s"
                + (f": {cause}" if cause else ""),
                file=sys.stderr,
            )
            return 1
        progress = outcome.progress
        say(
            {"event": "converged", "value": progress.value, "instance": progress.instance},
            f"converged: {relation_id} = {json.dumps(progress.value)}\n"
            f"  uncertainty {_mm(progress.std_translation)} {_deg(progress.std_rotation)} "
            f"from {progress.accepted} samples ({progress.rejected} rejected)",
        )
        if not args.save:
            return 0
        request = save_request(relation_id.source, relation_id.target, relation_id.type, progress)
        try:
            answer = save(session, keys, args.store, request)
        except StoreError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 1
        say({"event": "saved", **answer}, f"saved as {answer['edge']} in {answer['file']}")
    return 0

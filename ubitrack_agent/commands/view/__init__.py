"""``ubitrack view``: a live web view of the agent's data flow, and of its frames in 3D.

A small HTTP server (aiohttp: asynchronous, well kept, and the one HTTP dependency; the
standard library's ``http.server`` is documented as not for production use) bound to
``--bind``:``--port`` (loopback by default), joined to the zenoh network as a member. Every
``--every`` seconds it asks the agent for its status and the workers for their counters and
measures each served relation on its key (:mod:`.watch`); it serves one page that redraws,
every second, the data flow (laid out in the browser by the bundled dagre, or drawn by
Graphviz's ``dot`` where installed, if chosen), the agent's id and role, the hosts, the
components with their pattern and host, a row per queried relation with sparklines of its rate,
latency and error against a simulator's ground truth, and the reasons of unsolved queries; and
a 3D view (``/3d``, the bundled three.js) of every frame of the SRG placed by the live
relations (:mod:`.frame_watch`, :mod:`.frames`). :mod:`.pages` lists the paths. Everything is
served by the view itself: the pages need no network beyond it.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from typing import TYPE_CHECKING

from ubitrack_agent.net import config

if TYPE_CHECKING:
    from ubitrack_agent.commands.view.pages import Pages

DEFAULT_PORT = 8765


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "view",
        help="a live web page of the data flow with per-relation rate/latency/error "
        "sparklines, and the frames in 3D",
        description="Serve a live web view of the agent's state on http://BIND:PORT/: the data "
        "flow in the style of the paper's figure 6 (laid out in the browser by the bundled "
        "dagre, components grouped in their containers, with a legend; or drawn by Graphviz's "
        "dot where installed, if chosen on the page), the agent's id and role, the hosts, the "
        "components with their pattern and host, and for each queried relation sparklines of "
        "its rate (samples/s), latency (ms, arrival minus the sample's timestamp) and error "
        "(mm, against the ground truth of `ubitrack sim world`, where it runs), with the "
        "reasons of unsolved queries. On http://BIND:PORT/3d, every frame of the SRG in 3D, "
        "placed by the live 6D and 3D relations relative to a root you choose (default the "
        "tracker's frame), with axes, names, trails and uncertainty ellipsoids. Also "
        "/status.json, /series.json, /flow.json, /flow.dot, /flow.svg and "
        "/frames.json?root=FRAME. Watching never changes the plan: the view declares no query.",
    )
    parser.add_argument(
        "--bind", default="127.0.0.1", help="address to serve on (default: %(default)s)"
    )
    parser.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help="TCP port to serve on, 0 for a free one (default: %(default)s)",
    )
    parser.add_argument(
        "--every",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="poll the agent and measure the relations every SECONDS (default: %(default)s)",
    )
    parser.add_argument(
        "--history",
        type=float,
        default=120.0,
        metavar="SECONDS",
        help="how far back the sparklines reach (default: %(default)s)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.commands.status import render_svg
    from ubitrack_agent.commands.view.pages import Pages
    from ubitrack_agent.commands.view.snapshot import pattern_names
    from ubitrack_agent.commands.view.watch import Watcher
    from ubitrack_agent.graph.templates import load_templates
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.session import open_session

    try:
        settings = config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"ubitrack view: {exc}", file=sys.stderr)
        return 2
    if not (0 < args.every <= args.history) or not 0 <= args.port <= 65535:
        print(
            "ubitrack view: needs 0 < --every <= --history and --port in [0, 65535]",
            file=sys.stderr,
        )
        return 2
    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        watcher = Watcher(session, keys, pattern_names(load_templates()), args.every, args.history)
        watcher.start()
        try:
            pages = Pages(
                lambda: watcher.snapshot, render_svg, args.every, watcher.frame_watch.frames
            )
            return asyncio.run(_serve(pages, args.bind, args.port, keys.agent_status()))
        finally:
            watcher.close()


async def _serve(pages: Pages, bind: str, port: int, status_key: str) -> int:
    """Serve ``pages`` on ``bind``:``port`` until SIGTERM or SIGINT; 1 if it cannot listen."""
    from aiohttp import web

    async def handle(request: web.Request) -> web.Response:
        # Graphviz runs in the answer to /flow.svg: answer on a thread, not on the loop.
        reply = await asyncio.to_thread(
            pages.respond, request.method, request.path, request.query_string
        )
        return web.Response(status=reply.status, body=reply.body, headers=reply.all_headers())

    app = web.Application()
    app.router.add_route("*", "/{path:.*}", handle)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    try:
        await web.TCPSite(runner, bind, port).start()
    except OSError as exc:
        await runner.cleanup()
        print(f"ubitrack view: cannot serve on {bind}:{port}: {exc.strerror}", file=sys.stderr)
        return 1
    host, bound = runner.addresses[0][:2]
    shown = f"[{host}]" if ":" in host else host
    print(f"ubitrack view: http://{shown}:{bound}/ (the agent's status from {status_key})")
    sys.stdout.flush()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for number in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(number, stop.set)
    await stop.wait()
    await runner.cleanup()
    return 0

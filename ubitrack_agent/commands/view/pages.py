"""The live view's HTTP answers, a pure function of the request and the latest snapshot.

* ``/``: the page (``page.html``), with its script ``/view.js`` (and ``/dom.js``, shared with
  the 3D view's) and style ``/view.css``;
* ``/3d``: the 3D view of the frames (``page3d.html``, ``/view3d.js``);
* ``/vendor/...``: the bundled libraries the pages use, dagre and three.js, with their
  licenses (``vendor/README.md``);
* ``/status.json``: the agent's latest status, each component with its pattern, its worker's
  counters and its output rate (``ubitrack status --json`` and more); 503 ``{"error": why}``
  when no agent answers;
* ``/series.json``: each watched relation's series: rate, latency, error (``Series.as_json``);
* ``/flow.json``: the live data flow as nodes, wires and groups (:func:`.flow.flow_graph`),
  which the page lays out with dagre;
* ``/flow.dot``: the same in Graphviz DOT (``ubitrack status --dot``);
* ``/flow.svg``: the same drawn by Graphviz, where it is installed; 503 with the reason as text
  without it;
* ``/frames.json?root=FRAME``: every frame of the SRG placed relative to ``FRAME`` (default:
  the tracker's frame) by the live relations (:mod:`.frames`); 404 for a frame the SRG does
  not know, 503 before any status has named one.

Every request gets an answer: a path not listed is 404, a method other than GET or HEAD 405,
a query string 400 (except ``root`` on ``/frames.json``), a status that cannot be drawn 502.
The agent's status is network input: it is served as JSON and drawn by Graphviz into an SVG the
page shows as an image; the pages' scripts write it as text, never as markup, and the
``Content-Security-Policy`` runs no script but the view's own.
"""

from __future__ import annotations

import importlib.resources
import json
import threading
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.commands.view.flow import flow_dot, flow_graph
from ubitrack_agent.commands.view.snapshot import Snapshot

HTML, SCRIPT, STYLE = (f"text/{kind}; charset=utf-8" for kind in ("html", "javascript", "css"))
FILES = {
    "/": ("page.html", HTML),
    "/view.js": ("view.js", SCRIPT),
    "/view.css": ("view.css", STYLE),
    "/3d": ("page3d.html", HTML),
    "/view3d.js": ("view3d.js", SCRIPT),
    "/dom.js": ("dom.js", SCRIPT),
    "/vendor/dagre/dagre.min.js": ("vendor/dagre/dagre.min.js", SCRIPT),
    "/vendor/dagre/LICENSE": ("vendor/dagre/LICENSE", "text/plain; charset=utf-8"),
    "/vendor/three/three.module.min.js": ("vendor/three/three.module.min.js", SCRIPT),
    "/vendor/three/three.core.min.js": ("vendor/three/three.core.min.js", SCRIPT),
    "/vendor/three/LICENSE": ("vendor/three/LICENSE", "text/plain; charset=utf-8"),
}
"""The page's files (package data beside this module), by path."""

PATHS = (
    *FILES,
    "/status.json",
    "/series.json",
    "/flow.json",
    "/flow.dot",
    "/flow.svg",
    "/frames.json",
)
"""Every path the view answers."""

HEADERS = (
    ("Cache-Control", "no-store"),
    ("X-Content-Type-Options", "nosniff"),
    (
        "Content-Security-Policy",
        "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
        "img-src 'self' blob:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    ),
)
"""Headers of every answer: nothing cached (the page is live), no type sniffing, and no script,
style or image but the view's own (blob: is the flow picture the script fetched)."""

TEXT = "text/plain; charset=utf-8"
JSON = "application/json"


@dataclass(frozen=True)
class Reply:
    """An HTTP answer: status code, content type, body and extra headers."""

    status: int
    content_type: str
    body: bytes
    headers: tuple[tuple[str, str], ...] = ()

    def all_headers(self) -> dict[str, str]:
        """Its headers: content type, :data:`HEADERS` and its own."""
        return {"Content-Type": self.content_type, **dict(HEADERS), **dict(self.headers)}


def text(status: int, message: str) -> Reply:
    return Reply(status, TEXT, message.encode() + b"\n")


def as_json(status: int, data: Any) -> Reply:
    return Reply(status, JSON, json.dumps(data).encode())


class Pages:
    """Answers requests from the latest ``snapshot()``; ``render`` draws DOT as SVG (``None``
    and why not when it cannot: ``commands.status.render_svg``)."""

    def __init__(
        self,
        snapshot: Callable[[], Snapshot],
        render: Callable[[str], tuple[str | None, str | None]],
        every_s: float,
        frames: Callable[[str | None], dict[str, Any]],
    ) -> None:
        self._snapshot = snapshot
        self._frames = frames
        self._render = render
        self._every_s = every_s
        here = importlib.resources.files(__package__)
        self._files = {
            path: Reply(200, kind, here.joinpath(*name.split("/")).read_bytes())
            for path, (name, kind) in FILES.items()
        }
        self._drawn: tuple[str, tuple[str | None, str | None]] = ("", (None, None))
        self._drawing = threading.Lock()

    def respond(self, method: str, path: str, query: str) -> Reply:
        """The answer to ``method path?query`` (``query`` the raw query string)."""
        if method not in ("GET", "HEAD"):
            return Reply(405, TEXT, b"only GET and HEAD\n", (("Allow", "GET, HEAD"),))
        if path == "/frames.json":
            return self._placed(query)
        if query:
            return text(400, f"{path} takes no query parameters")
        if path in self._files:
            return self._files[path]
        snapshot = self._snapshot()
        if path == "/status.json":
            if snapshot.status is None:
                return as_json(503, {"error": snapshot.problem})
            return as_json(200, snapshot.status)
        if path == "/series.json":
            return as_json(
                200,
                {
                    "taken_ns": snapshot.taken_ns,
                    "every_s": self._every_s,
                    "relations": snapshot.relations,
                    "counters": snapshot.counters,
                },
            )
        if path == "/flow.json":
            return self._graph(snapshot)
        if path in ("/flow.dot", "/flow.svg"):
            return self._flow(snapshot, svg=path == "/flow.svg")
        return text(404, f"no page {path[:200]!r}: the view serves {', '.join(PATHS)}")

    def _placed(self, query: str) -> Reply:
        """``/frames.json``: the frames relative to the ``root`` the query names, if any."""
        try:
            fields = urllib.parse.parse_qs(query, strict_parsing=bool(query), max_num_fields=2)
        except ValueError as exc:
            return text(400, f"/frames.json takes ?root=FRAME: {str(exc)[:200]}")
        if set(fields) - {"root"} or any(len(values) != 1 for values in fields.values()):
            return text(400, "/frames.json takes one parameter, ?root=FRAME")
        placed = self._frames(fields["root"][0] if fields else None)
        if "error" not in placed:
            return as_json(200, placed)
        return as_json(404 if placed.get("known") else 503, placed)  # an unknown root; no SRG

    def _graph(self, snapshot: Snapshot) -> Reply:
        """``/flow.json``: the flow's nodes, wires and groups, for the page to lay out."""
        if snapshot.status is None:
            return as_json(503, {"error": snapshot.problem})
        try:
            return as_json(200, flow_graph(snapshot.status, snapshot.rates))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a malformed status
            return as_json(502, {"error": f"the agent's status cannot be drawn: {exc!r}"[:300]})

    def _flow(self, snapshot: Snapshot, svg: bool) -> Reply:
        if snapshot.status is None:
            return text(503, str(snapshot.problem))
        try:
            dot = flow_dot(snapshot.status, snapshot.rates)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a malformed status
            return text(502, f"the agent's status cannot be drawn: {type(exc).__name__} {exc}")
        if not svg:
            return Reply(200, "text/vnd.graphviz; charset=utf-8", dot.encode())
        picture, failed = self._draw(dot)
        if picture is None:
            return text(503, f"no picture: {failed}")
        return Reply(200, "image/svg+xml", picture.encode())

    def _draw(self, dot: str) -> tuple[str | None, str | None]:
        """``render(dot)``, drawn again only when the flow's DOT changed."""
        with self._drawing:
            if self._drawn[0] != dot:
                self._drawn = (dot, self._render(dot))
            return self._drawn[1]

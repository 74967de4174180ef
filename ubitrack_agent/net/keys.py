"""Every zenoh key expression the middleware uses, built in this one module.

Layout (all below ``<prefix>/<domain>``, default ``ubitrack/default``)::

    <root>/provider/<provider>       liveliness token of a provider (sensor, database)
    <root>/fragment/<provider>       queryable: the provider's SRG fragment (JSON)
    <root>/data/<edge-id>            measurements of one SRG edge (msgpack, see core.codec);
                                     measured edges are <provider>/<edge-name>; the key is also
                                     a queryable answering the latest value
    <root>/data/<provider>           the provider's data liveness report: its quiet edges
                                     (JSON, io.provider; one chunk below data, where an edge's
                                     data key always has two)
    <root>/query/<from>/<to>/<type>/<kind>/<host>/<app>[/<label>+<label>...]
                                     liveliness token of an application's query: the key is
                                     the whole description, so liveliness alone rebuilds state;
                                     <kind> is static, dynamic or recalibrate (below)
    <root>/relation/<from>/<to>/<type>/<kind>
                                     the stable key on which a queried relation is delivered
    <root>/answer/<from>/<to>/<type>/<kind>
                                     the active agent's answer to the query: the flow that
                                     serves it, or why none can (JSON, agent.answers); also a
                                     queryable answering the latest
    <root>/agent                     liveliness token of the active agent
    <root>/agent/status              queryable: the active agent's state (JSON)
    <root>/agent/clock               queryable: the active agent's clock, the reference the
                                     host managers measure their offsets to (net.clock)
    <root>/agents/<id>               liveliness token of every agent process, active or
                                     standby (agent.election: one active agent per domain)
    <root>/agents/<id>/active        liveliness token the active agent adds to its own
    <root>/agents/<id>/status        queryable: that agent's state, a standby's too (JSON)
    <root>/host/<name>               liveliness token of a host manager
    (ubitrack_agent.services.host) <root>/host/<name>/request       queryable: start, stop, status
    requests (JSON) <root>/host/<name>/exited        a worker that ended without being asked (JSON,
    put) <root>/pool/<id>                 an idle pre-started worker: its token, and where its
                                     component specification (or group) is sent
    <root>/container/<name>/<incarnation>
                                     liveliness token of a container
                                     (ubitrack_agent.services.container) once it takes commands on
                                     <root>/control/<name>
    <root>/left/<name>               components that left container <name> by their own stop
                                     command (JSON, put): its host manager forgets them
    <root>/worker/<instance>/<incarnation>
                                     liveliness token of a running pattern worker; the
                                     incarnation (``<pid>.<nonce>``) tells one process's token
                                     from another's, so a late removal of an earlier process's
                                     token is not taken for the current one's
    <root>/control/<instance>        rewire / reconfigure a running worker (JSON, put)
    <root>/control/<instance>/<incarnation>
                                     the same, to one process only (stopping a duplicate)
    <root>/status/<instance>         a worker's counters (JSON, queryable)
    <root>/progress/<from>/<to>/<type>/<static|recalibrate>
                                     progress of a static relation computed over time (JSON,
                                     net.progress); also a queryable answering the latest
    <root>/store/<name>              queryable of a calibration store: save requests (JSON)
    <root>/truth/<from>/<to>         queryable of a simulated world: the ground truth of the
                                     relation (msgpack), at ``?t=<ns>`` or now

The kind chunk says what is asked: ``dynamic`` a relation that may change, ``static`` a rigid
one (answered by a measured static edge, e.g. a stored calibration, or calibrated over time),
``recalibrate`` the same rigid relation calibrated again from dynamic inputs while ignoring the
measured static edges between its two frames (in either direction). A recalibration has keys
of its own, so what reads the static relation meanwhile is not disturbed.

Names that end up inside keys (frames, edge ids, domains) are checked chunk by chunk: no empty
chunks, no wildcards (``*``, ``$``), no ``#``/``?`` (selector syntax), no ``@`` (zenoh's
admin space) and no whitespace, so a hostile name can never widen a subscription.

Keys read from the network (liveliness tokens, exit reports) go through
:meth:`KeySpace.parse_token`, which is total: it returns a :class:`Token` or a
:class:`KeyRejection` naming the reason, whatever the key holds, and reads no key longer than
:data:`MAX_KEY_CHARS`.
"""

from __future__ import annotations

from dataclasses import dataclass

from ubitrack_agent.core.names import check_label, check_name, shown

MAX_KEY_CHARS = 1024
"""Longest key read from the network; a longer one is rejected unread."""


def validate_key_chunks(text: str, single_chunk: bool = False) -> str:
    """Return ``text`` if it is a safe literal key (one chunk if ``single_chunk``), else raise."""
    if not isinstance(text, str) or not text:
        raise ValueError("must be a non-empty string")
    if len(text) > MAX_KEY_CHARS:
        raise ValueError(f"{shown(text)} is longer than {MAX_KEY_CHARS} characters")
    chunks = text.split("/")
    if single_chunk and len(chunks) > 1:
        raise ValueError(f"{shown(text)} must not contain '/'")
    for chunk in chunks:
        if not chunk:
            raise ValueError(f"{shown(text)} has an empty chunk (leading, trailing or double '/')")
        check_name(chunk)
    return text


TOKEN_KINDS = (
    "provider",
    "query",
    "worker",
    "pool",
    "container",
    "host",
    "host_exited",
    "agent",
    "active_agent",
)
"""The kinds of key :meth:`KeySpace.parse_token` reads."""

KINDS: dict[str, tuple[bool, bool]] = {
    "dynamic": (False, False),
    "static": (True, False),
    "recalibrate": (True, True),
}
"""The kind chunk of query and relation keys, and the ``(static, recalibrate)`` it stands for."""


@dataclass(frozen=True)
class RelationId:
    """A relationship an application asks for: ``source -> target`` of ``type``.

    ``recalibrate`` (only with ``static``) asks to calibrate the static relation again from
    dynamic inputs, ignoring the measured static edges between the two frames (the stored
    calibration being replaced); it has its own relation and progress keys.
    """

    source: str
    target: str
    type: str
    static: bool = False
    recalibrate: bool = False

    def __post_init__(self) -> None:
        for name in (self.source, self.target, self.type):
            validate_key_chunks(name, single_chunk=True)
        if self.source == self.target:
            raise ValueError(f"a relation joins two different frames, got {self.source!r} twice")
        if self.recalibrate and not self.static:
            raise ValueError("a recalibration is of a static relation: give static=True")

    @property
    def kind(self) -> str:
        """The kind chunk of its keys: ``dynamic``, ``static`` or ``recalibrate``."""
        return next(k for k, flags in KINDS.items() if flags == (self.static, self.recalibrate))

    @property
    def chunks(self) -> str:
        return f"{self.source}/{self.target}/{self.type}/{self.kind}"

    def __str__(self) -> str:
        kind = "" if self.kind == "dynamic" else f" {self.kind}"
        return f"{self.source}->{self.target}:{self.type}{kind}"


@dataclass(frozen=True)
class Token:
    """A key from the network, parsed: its ``kind`` (one of :data:`TOKEN_KINDS`), its ``name``
    (provider id, worker instance, pool id, host name; for a query the application), for a
    query the ``relation`` asked for, the ``host`` the application runs on and the ``labels``
    it requires of the host running the relation's last hop, and for a
    worker the ``incarnation`` of the process."""

    kind: str
    name: str
    relation: RelationId | None = None
    incarnation: str = ""
    host: str = ""
    labels: frozenset[str] = frozenset()


@dataclass(frozen=True)
class KeyRejection:
    """A key from the network that :meth:`KeySpace.parse_token` refused, and why. ``key`` is
    cut to :data:`MAX_KEY_CHARS`; it is network text, to be logged with ``%r``."""

    kind: str
    key: str
    reason: str

    @property
    def counter(self) -> str:
        """The name of the counter of such rejections (``rejected_worker_keys``)."""
        return f"rejected_{self.kind}_keys"


def _relation(source: str, target: str, edge_type: str, kind: str, key: str) -> RelationId:
    """The relation named by the chunks of ``key``; ``ValueError`` for an unknown kind."""
    if kind not in KINDS:
        raise ValueError(f"{key!r}: kind {kind!r} is not one of {sorted(KINDS)}")
    return RelationId(source, target, edge_type, *KINDS[kind])


FIRST_CHUNKS = (
    "agent", "agents", "answer", "container", "control", "data", "fragment", "host", "left",
    "pool", "progress", "provider", "query", "relation", "status", "store", "truth", "worker",
)  # fmt: skip
"""Every first chunk below the root, the kinds of key in the layout above (``net.access``
grants reading by them)."""


class KeySpace:
    """Builds the keys of one ``<prefix>/<domain>`` root."""

    def __init__(self, root: str) -> None:
        self.root = validate_key_chunks(root)

    def data(self, edge_id: str) -> str:
        """Key on which the measurements of edge ``edge_id`` flow."""
        return f"{self.root}/data/{validate_key_chunks(edge_id)}"

    def liveness(self, provider: str) -> str:
        """Key on which ``provider`` puts its data liveness report (``io.provider``)."""
        return f"{self.root}/data/{validate_key_chunks(provider, single_chunk=True)}"

    def all_liveness(self) -> str:
        """Selector of every provider's liveness report (one chunk below ``data``: no edge's
        data key)."""
        return f"{self.root}/data/*"

    def parse_liveness(self, key: str) -> str:
        """The provider id of a liveness report's key; ``ValueError`` if malformed."""
        return self._parse_name(key, "data")

    def worker(self, instance: str, incarnation: str) -> str:
        """Liveliness token of the worker process ``incarnation`` running component
        ``instance``."""
        validate_key_chunks(instance, single_chunk=True)
        return (
            f"{self.root}/worker/{instance}/{validate_key_chunks(incarnation, single_chunk=True)}"
        )

    def worker_tokens(self, instance: str) -> str:
        """Selector of the tokens of every process running component ``instance``."""
        return f"{self.root}/worker/{validate_key_chunks(instance, single_chunk=True)}/*"

    def control(self, instance: str) -> str:
        """Key on which the agent sends reconfiguration commands to ``instance``."""
        return f"{self.root}/control/{validate_key_chunks(instance, single_chunk=True)}"

    def control_incarnation(self, instance: str, incarnation: str) -> str:
        """Key on which one process (``incarnation``) running ``instance`` takes commands."""
        return f"{self.control(instance)}/{validate_key_chunks(incarnation, single_chunk=True)}"

    def status(self, instance: str) -> str:
        """Queryable that answers ``instance``'s counters."""
        return f"{self.root}/status/{validate_key_chunks(instance, single_chunk=True)}"

    def all_statuses(self) -> str:
        """Selector reaching every worker's status queryable."""
        return f"{self.root}/status/*"

    def provider(self, provider: str) -> str:
        """Liveliness token announcing ``provider``."""
        return f"{self.root}/provider/{validate_key_chunks(provider, single_chunk=True)}"

    def fragment(self, provider: str) -> str:
        """Queryable serving ``provider``'s SRG fragment."""
        return f"{self.root}/fragment/{validate_key_chunks(provider, single_chunk=True)}"

    def measured(self, provider: str, edge_name: str) -> str:
        """Data key of the measured edge ``edge_name`` of ``provider``."""
        validate_key_chunks(provider, single_chunk=True)
        return self.data(f"{provider}/{validate_key_chunks(edge_name, single_chunk=True)}")

    def truth(self, source: str, target: str) -> str:
        """Queryable answering the simulated ground truth of ``source -> target``."""
        validate_key_chunks(source, single_chunk=True)
        return f"{self.root}/truth/{source}/{validate_key_chunks(target, single_chunk=True)}"

    def query(
        self,
        relation: RelationId,
        application: str,
        host: str,
        labels: frozenset[str] = frozenset(),
    ) -> str:
        """Liveliness token of the query for ``relation`` of ``application``, running on
        ``host`` (the agent places the relation's last hop near it), which may require
        ``labels`` of the host running that last hop (an extra chunk, joined with ``+``)."""
        app = validate_key_chunks(application, single_chunk=True)
        machine = validate_key_chunks(host, single_chunk=True)
        required = "/" + "+".join(sorted(map(check_label, labels))) if labels else ""
        return f"{self.root}/query/{relation.chunks}/{machine}/{app}{required}"

    def relation(self, relation: RelationId) -> str:
        """The stable key on which ``relation`` is delivered, whatever flow computes it."""
        return f"{self.root}/relation/{relation.chunks}"

    def answer(self, relation: RelationId) -> str:
        """Where the active agent says how it serves ``relation``, or why it cannot."""
        return f"{self.root}/answer/{relation.chunks}"

    def all_answers(self) -> str:
        """Selector of every answer key."""
        return f"{self.root}/answer/**"

    def parse_relation(self, key: str) -> RelationId:
        """The relation of a relation key; ``ValueError`` if malformed."""
        prefix = f"{self.root}/relation/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not a relation key under {prefix!r}")
        parts = key[len(prefix) :].split("/")
        if len(parts) != 4:
            raise ValueError(f"{key!r}: expected relation/<from>/<to>/<type>/<kind>")
        return _relation(*parts, key=key)

    def progress(self, relation: RelationId) -> str:
        """Where the computation of a static ``relation`` from dynamic inputs (a calibration, or
        a recalibration on keys of its own) reports its progress (``net.progress``)."""
        return f"{self.root}/progress/{relation.chunks}"

    def store(self, name: str) -> str:
        """Queryable of the calibration store ``name``: save requests (JSON)."""
        return f"{self.root}/store/{validate_key_chunks(name, single_chunk=True)}"

    def parse_query(self, key: str) -> tuple[RelationId, str, str, frozenset[str]]:
        """``(relation, application, host, labels)`` from a query token key; ``ValueError``
        if malformed."""
        prefix = f"{self.root}/query/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not a query key under {prefix!r}")
        parts = key[len(prefix) :].split("/")
        if len(parts) not in (6, 7):
            raise ValueError(
                f"{key!r}: expected query/<from>/<to>/<type>/<kind>/<host>/<app>[/<labels>]"
            )
        *chunks, host, app = parts[:6]
        labels = frozenset(map(check_label, parts[6].split("+"))) if parts[6:] else frozenset()
        relation = _relation(*chunks, key=key)
        return (
            relation,
            validate_key_chunks(app, single_chunk=True),
            validate_key_chunks(host, single_chunk=True),
            labels,
        )

    def parse_provider(self, key: str) -> str:
        """The provider id of a provider token key; ``ValueError`` if malformed."""
        return self._parse_name(key, "provider")

    def agent(self) -> str:
        """Liveliness token of the agent."""
        return f"{self.root}/agent"

    def agent_status(self) -> str:
        """Queryable answering the active agent's state."""
        return f"{self.root}/agent/status"

    def agent_clock(self) -> str:
        """Queryable answering the active agent's clock (``net.clock``)."""
        return f"{self.root}/agent/clock"

    def agent_member(self, agent: str) -> str:
        """Liveliness token of the agent process ``agent``, active or standby."""
        return f"{self.root}/agents/{validate_key_chunks(agent, single_chunk=True)}"

    def agent_active(self, agent: str) -> str:
        """Liveliness token the active agent ``agent`` adds to its own."""
        return f"{self.agent_member(agent)}/active"

    def agent_member_status(self, agent: str) -> str:
        """Queryable answering the state of the agent process ``agent``."""
        return f"{self.agent_member(agent)}/status"

    def all_agent_statuses(self) -> str:
        """Selector reaching every agent process's status queryable."""
        return f"{self.root}/agents/*/status"

    def all_agents(self) -> str:
        """Selector of every agent process's token."""
        return f"{self.root}/agents/*"

    def all_active_agents(self) -> str:
        """Selector of every active agent's token (one, but for a moment after a split
        network joins again)."""
        return f"{self.root}/agents/*/active"

    def parse_agent(self, key: str) -> str:
        """The agent id of an agent token key; ``ValueError`` if malformed."""
        return self._parse_name(key, "agents")

    def parse_active_agent(self, key: str) -> str:
        """The agent id of an active agent's token key; ``ValueError`` if malformed."""
        suffix = "/active"
        if not key.endswith(suffix):
            raise ValueError(f"{key!r} is not an active agent key (<root>/agents/<id>/active)")
        return self.parse_agent(key[: -len(suffix)])

    def pool(self, worker: str) -> str:
        """Token of an idle pre-started worker, and the key its specification is sent on."""
        return f"{self.root}/pool/{validate_key_chunks(worker, single_chunk=True)}"

    def all_pools(self) -> str:
        """Selector of every idle pool worker's token."""
        return f"{self.root}/pool/*"

    def parse_pool(self, key: str) -> str:
        """The pool id of a pool token key; ``ValueError`` if malformed."""
        return self._parse_name(key, "pool")

    def container(self, name: str, incarnation: str) -> str:
        """Liveliness token of the process ``incarnation`` (``<pid>.<nonce>``) running the
        container ``name``, declared once it takes commands on :meth:`control` ``(name)``."""
        validate_key_chunks(incarnation, single_chunk=True)
        return f"{self.root}/container/{validate_key_chunks(name, single_chunk=True)}/{incarnation}"

    def all_containers(self) -> str:
        """Selector of every container's token."""
        return f"{self.root}/container/*/*"

    def parse_container(self, key: str) -> tuple[str, str]:
        """The name and incarnation of a container token key; ``ValueError`` if malformed."""
        return self._parse_incarnation(key, "container")

    def container_left(self, name: str) -> str:
        """Where container ``name`` reports components that left it by their own stop
        command (not by its host manager's remove)."""
        return f"{self.root}/left/{validate_key_chunks(name, single_chunk=True)}"

    def all_container_left(self) -> str:
        """Selector of every container's reports of components that left."""
        return f"{self.root}/left/*"

    def parse_container_left(self, key: str) -> str:
        """The container's name in a left report's key; ``ValueError`` if malformed."""
        return self._parse_name(key, "left")

    def all_providers(self) -> str:
        """Selector of every provider's token."""
        return f"{self.root}/provider/*"

    def all_queries(self) -> str:
        """Selector of every application query's token."""
        return f"{self.root}/query/**"

    def all_workers(self) -> str:
        """Selector of every running worker's token."""
        return f"{self.root}/worker/*/*"

    def parse_worker(self, key: str) -> tuple[str, str]:
        """The instance and incarnation of a worker token key; ``ValueError`` if malformed."""
        return self._parse_incarnation(key, "worker")

    def _parse_incarnation(self, key: str, kind: str) -> tuple[str, str]:
        """The name and incarnation after ``<root>/<kind>/`` in ``key``; ``ValueError``
        otherwise."""
        name, _, incarnation = self._parse_name(key, kind, chunks=2).partition("/")
        return name, incarnation

    def host(self, name: str) -> str:
        """Liveliness token of the host manager ``name`` (one per machine)."""
        return f"{self.root}/host/{validate_key_chunks(name, single_chunk=True)}"

    def host_request(self, name: str) -> str:
        """Queryable of host manager ``name`` taking start, stop and status requests."""
        return f"{self.host(name)}/request"

    def host_exited(self, name: str) -> str:
        """Where host manager ``name`` reports workers that ended without being asked."""
        return f"{self.host(name)}/exited"

    def all_hosts(self) -> str:
        """Selector of every host manager's token."""
        return f"{self.root}/host/*"

    def all_host_exits(self) -> str:
        """Selector of every host manager's exit reports."""
        return f"{self.root}/host/*/exited"

    def parse_host(self, key: str) -> str:
        """The name of a host manager's token key; ``ValueError`` if malformed."""
        return self._parse_name(key, "host")

    def parse_host_exited(self, key: str) -> str:
        """The host manager's name in an exit report's key; ``ValueError`` if malformed."""
        suffix = "/exited"
        if not key.endswith(suffix):
            raise ValueError(f"{key!r} is not a host exit key (<root>/host/<name>/exited)")
        return self.parse_host(key[: -len(suffix)])

    def pattern(self, *chunks: str) -> str:
        """The key expression ``<root>/<chunks>``, whose chunks may be zenoh wildcards (``*``,
        ``**``, ``$*``): for access-control rules (``net.access``), never declared or
        published on; the first chunk is one of the layout's above."""
        return "/".join((self.root, *chunks))

    def parse_token(self, kind: str, key: str) -> Token | KeyRejection:
        """The ``kind`` key ``key`` read from the network (a token's or an exit report's), or
        why it is refused; never raises for any ``key``. ``ValueError`` for an unknown ``kind``
        (a programming error, not network input)."""
        if kind not in TOKEN_KINDS:
            raise ValueError(f"unknown token kind {kind!r}, expected one of {TOKEN_KINDS}")
        if len(key) > MAX_KEY_CHARS:
            reason = f"{len(key)} characters, at most {MAX_KEY_CHARS}"
            return KeyRejection(kind, key[:MAX_KEY_CHARS], reason)
        try:
            if kind == "query":
                relation, application, host, labels = self.parse_query(key)
                return Token(kind, application, relation, host=host, labels=labels)
            if kind in ("worker", "container"):
                name, incarnation = getattr(self, f"parse_{kind}")(key)
                return Token(kind, name, incarnation=incarnation)
            return Token(kind, getattr(self, f"parse_{kind}")(key))
        except ValueError as exc:
            return KeyRejection(kind, key, str(exc))

    def _parse_name(self, key: str, kind: str, chunks: int = 1) -> str:
        """The ``chunks`` chunks after ``<root>/<kind>/`` in ``key``; ``ValueError``
        otherwise."""
        prefix = f"{self.root}/{kind}/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not a {kind} key under {prefix!r}")
        name = validate_key_chunks(key[len(prefix) :])
        if name.count("/") != chunks - 1:
            raise ValueError(f"{key!r}: expected {chunks} chunk(s) after {prefix!r}")
        return name

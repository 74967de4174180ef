"""Hostile input for every network entry point (issue 11), as hypothesis strategies, shared by
the fuzz tests (``test_fuzz_agent.py``, ``test_fuzz_worker.py``) and the longer fuzz benchmark
(``bench/fuzz_bench.py``).

Agent side: liveliness tokens with hostile names, query keys, provider fragments hostile in
value, shape, nesting and size, host exit reports, status queries. Worker side: measurements,
control commands, pool specifications, host requests. None of them is valid where it is sent:
a valid stop or specification would change the system on purpose."""

from __future__ import annotations

import json
import math
import threading
import time

from hypothesis import strategies as st

from tests.unit.test_codec import hostile_messages, measurements
from ubitrack_agent.core import Pose, decode, encode
from ubitrack_agent.core.names import check_name
from ubitrack_agent.core.timeline import MAX_FUTURE_NS
from ubitrack_agent.graph.srg import EDGE_TYPES
from ubitrack_agent.net.host_protocol import Start, encode_request
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec


def invalid(name: str) -> bool:
    """Whether ``name`` breaks the name rule (``core.names.check_name``)."""
    try:
        check_name(name)
    except ValueError:
        return True
    return False


HOSTILE_NAMES = st.sampled_from(
    ["*", "**", "a b", "a$*b", "Ä", "@x", "a/b", "x" * 2000, "a\nb", "\x00", "$*"]
) | st.text(max_size=30).filter(invalid)
GOOD_NAMES = st.from_regex(r"\Afz-[a-z0-9]{1,8}\Z")
TOKEN_KINDS = st.sampled_from(["provider", "worker", "host", "pool", "agents"])
QUERY_CHUNKS = st.lists(
    st.one_of(HOSTILE_NAMES, st.sampled_from(["FZ1", "FZ2", "6D", "7D", "dynamic"])),
    min_size=1,
    max_size=7,
)
"""The chunks of a query key after ``<root>/query/``."""
HOSTILE_NUMBERS = st.sampled_from(
    [1e200, -1e200, 10**400, -(10**400), math.nan, math.inf, -math.inf, -1e-9, 1e6]
) | st.one_of(st.text(max_size=5), st.lists(st.integers(), max_size=3), st.booleans(), st.none())
"""Out of range for sigma, rate and latency alike (``graph.srg.QUALITY_BOUNDS``), or no number."""
NOT_A_WORD = st.text(max_size=8).filter(lambda text: text not in {"push", "pull", *EDGE_TYPES})
BASE_EDGE = {
    "name": "e",
    "from": "FZ1",
    "to": "FZ2",
    "type": "6D",
    "static": False,
    "mode": "push",
    "sigma": 0.001,
    "rate": 50.0,
}


def with_field(field: str, value) -> dict:
    """``BASE_EDGE`` with one field replaced."""
    return {**BASE_EDGE, field: value}


EDGES = st.one_of(
    st.builds(with_field, st.sampled_from(["sigma", "rate", "latency"]), HOSTILE_NUMBERS),
    st.builds(with_field, st.sampled_from(["name", "from", "to"]), HOSTILE_NAMES),
    st.builds(with_field, st.sampled_from(["type", "mode", "static"]), NOT_A_WORD),
    st.builds(with_field, st.sampled_from(["colour", "provider", "id"]), st.integers()),
)


def fragment(provider: str, edges: list) -> bytes:
    """A provider fragment as served on ``<root>/fragment/<provider>``."""
    return json.dumps({"provider": provider, "edges": edges}).encode()


def hostile_fragment(provider: str) -> st.SearchStrategy[bytes]:
    """Fragments that must all be rejected, each hostile in one way."""
    many = [{**BASE_EDGE, "name": f"e{i}"} for i in range(1001)]
    return st.one_of(
        st.builds(lambda e: fragment(provider, [e]), EDGES),
        st.builds(lambda e: fragment(provider, [BASE_EDGE, e]), EDGES),
        st.just(fragment(provider, many)),
        st.just(fragment("someone-else", [BASE_EDGE])),
        st.just(fragment(provider, [])),
        st.just(b'{"provider": "' + provider.encode() + b'", "edges": ' + b"[" * 20000),
        st.just(b'{"provider": "p", "edges": [' + b"[" * 5000 + b"]" * 5000 + b"]}"),
        st.just(fragment(provider, [with_field("name", "n" * 300_000)])),
        st.just(b" " * (2 << 20)),
        st.binary(max_size=200),
        st.just(b'{"provider": 1' + b"0" * 5000 + b', "edges": []}'),
    )


EXIT_REPORT_HOSTS = st.one_of(HOSTILE_NAMES, st.just("vm"), GOOD_NAMES)
EXIT_REPORT_PAYLOADS = st.one_of(
    st.binary(max_size=100),
    st.builds(
        lambda obj: json.dumps(obj).encode(),
        st.dictionaries(
            st.sampled_from(["instance", "run", "pid", "reason"]),
            st.text(max_size=5) | st.integers(),
        ),
    ),
    st.just(b"[" * 20000),
)
STATUS_PARAMETERS = st.text(max_size=40)
STATUS_PAYLOADS = st.binary(max_size=100)


class FragmentServer:
    """One queryable on every fragment key, answering the hostile providers' fragments."""

    def __init__(self, session, keys: KeySpace) -> None:
        self.payloads: dict[str, bytes] = {}
        self._prefix = keys.fragment("x")[:-1]
        self._queryable = session.declare_queryable(self._prefix + "*")
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        for query in self._queryable:
            with query:
                payload = self.payloads.get(str(query.key_expr)[len(self._prefix) :])
                if payload is not None:
                    query.reply(query.key_expr, payload)

    def close(self) -> None:
        self._queryable.undeclare()


def rss_mb(pid: int) -> float:
    """The resident memory of process ``pid`` in MB."""
    with open(f"/proc/{pid}/status", encoding="ascii") as status:
        line = next(line for line in status if line.startswith("VmRSS:"))
    return int(line.split()[1]) / 1024


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=20,
)


def nested_json(depth: int, as_map: bool) -> bytes:
    """JSON nested ``depth`` deep (the parser's recursion limit is about a thousand)."""
    if as_map:
        return b'{"a": ' * depth + b"1" + b"}" * depth
    return b"[" * depth + b"]" * depth


hostile_json = st.one_of(
    st.binary(max_size=300),
    json_values.map(lambda value: json.dumps(value).encode()),
    st.builds(nested_json, st.integers(30, 200_000), st.booleans()),
    st.integers(70_000, 300_000).map(lambda n: b'{"a": "' + b"x" * n + b'"}'),  # oversized
)


@st.composite
def future_poses(draw) -> bytes:
    """A valid pose stamped beyond the bound ahead of the clock: a day, or just past it."""
    ahead = draw(st.sampled_from([86_400 * 10**9, MAX_FUTURE_NS + 10**9, 2**62]))
    return encode(Pose(time.time_ns() + ahead, [0, 0, 0, 1], [1.0, 2.0, 3.0]))


measurement_payloads = st.one_of(
    hostile_messages,
    future_poses(),
    st.binary(max_size=200),
    measurements.map(encode).filter(lambda data: decode(data).timestamp_ns < time.time_ns()),
)


@st.composite
def control_commands(draw) -> bytes:
    """Control commands with the right field names and wrong values, or anything at all (never
    a valid stop: that would end the run on purpose)."""
    if draw(st.booleans()):
        return draw(hostile_json)
    name = draw(st.sampled_from(["inputs", "parameters", "relations", "stop", "colour"]))
    value = draw(json_values.filter(lambda v: v is not True))
    return json.dumps({name: value}).encode()


@st.composite
def pool_specifications(draw, valid: ComponentSpec) -> bytes:
    """A specification with one field broken (never a valid one: a pool member would run it),
    or anything at all."""
    if draw(st.booleans()):
        return draw(hostile_json)
    broken = {
        "instance": draw(
            st.sampled_from(["*", "a b", "", "a/b", "Ä", "$*"])
            | json_values.filter(lambda v: not isinstance(v, str))
        ),
        "service": draw(st.sampled_from(["os.system", "../relay", "relay*"])),
        "parameters": {"x" + draw(st.text(max_size=5)): draw(json_values)},
        "inputs": draw(json_values.filter(lambda v: v != [])),
        "tolerance_ms": draw(st.sampled_from([-1, 1e400, 2**70, "5"])),
    }
    name = draw(st.sampled_from(sorted(broken)))
    return json.dumps({**valid.as_dict(), name: broken[name]}).encode()


@st.composite
def host_requests(draw, valid: ComponentSpec) -> bytes:
    """Host manager requests that must all be refused: anything at all, a start of an unknown
    service, or a request with a wrong operation or fields."""
    if draw(st.booleans()):
        return draw(hostile_json)
    op = draw(st.sampled_from(["start", "stop", "status", "launch", None]))
    if op == "start":
        return encode_request(Start(valid)).replace('"relay"', '"nope"').encode()
    return json.dumps({"op": op, "instance": draw(json_values), "spec": draw(json_values)}).encode()

"""Who puts on a relation key while the data flow changes: make before break, one stream.

The producer of a queried relation puts its output on the relation's stable key
(``agent.materialise``). When the agent replaces a derivation, the new flow is started beside
the old one, which is stopped ``HAND_OVER_HOLD_S`` after the new one runs (``agent.runtime``,
``_retire``), or ``STANDBY_S`` after it lost a sensor (``agent.standby``): for a while both
producers compute the relation, often the same instants (both
driven by one tracker's samples). Each watches the key (a subscriber: it sees the other's
puts; its own it knows, :class:`Watch`) and its hand-over key (:func:`hand_over_key`), and
keeps these rules, so that the application sees one stream (issue [seamless];
``docs/protocol.md``, "What an application sees while the flow behind its key changes"):

1. **Order.** A sample whose timestamp is not after the newest one seen on the key is not put:
   no duplicate, no instant out of order.
2. **Make before break.** A producer that finds another one putting on the key does not put
   until its own estimate is ready: its covariance's trace is at most :data:`READY_RATIO`
   times that of the other's latest sample (measurements with covariances of one shape), and
   it has computed for :data:`WARM_S` at least unless it is at most :data:`CLEARLY_RATIO`
   times as uncertain (a fused flow after a camera-only one claims at once). Until then
   the old flow delivers, as long as the agent keeps it: when the agent stops it, the key is
   free at once (rule 5), so a new flow that is never as certain (a camera alone after a
   fusion that runs on with the camera alone) takes over then, not before. It waits however
   long that takes: a *spare* flow (``agent.spares``: the derivation left best when a sensor
   of the chosen one is lost, started beside it) is such a producer for as long as the chosen
   flow is the more certain, and takes the key by this rule within a sample of the holder
   losing that sensor. A holder nobody stops (no agent) keeps the key while it puts.
3. **Claim, then put.** Ready, it puts a claim on the hand-over key and nothing on the
   relation key until the producer holding it answers that it has stopped, and after which
   instant (the newest it put); then it puts what comes after that instant. Two producers
   computing the same instants never both put one: the holder stops before it answers. With
   no answer within :data:`CLAIM_TIMEOUT_S` it puts anyway if the key is quiet (a holder that
   died or hung meanwhile), and claims again if the holder still puts (an answer late on a
   loaded machine, or a message lost): putting then would put the holder's instants twice.
   The answer names the claimer it answers: another claimer pending then knows the key taken
   and claims again from its new holder (rule 2), and of two claimers neither holding the
   key, the one with the higher id withdraws (a claim with nobody to answer it, taken after
   the timeout by one producer only).
4. **Yield.** A producer that receives a claim while it holds the key stops putting there and
   answers; it puts again only once the claimer has been quiet (a newer flow that died). A
   producer that finds the key quiet while the producer holding it is alive (a fusion waiting
   for an input that stopped; a key it has seen nothing on is quiet only a quiet time after it
   began to watch it, as the holder's next sample may be on its way when a new flow computes
   its first) claims it and puts nothing until the answer: the holder, only
   late, stops before it answers, so the two never put one instant each (the repeated instants
   a put at once caused). A producer that finds the key quiet with no holder alive puts at once
   and claims it all the same. The holder is the producer that claimed the key last: the
   others see its claim, and one starting asks (the holder replies ``{"holds": <producer>}`` to
   a query on the hand-over key).
5. **A holder gone is gone at once.** Each producer declares a liveliness token
   (:func:`producer_token`). When the holder's token leaves (its process killed, or stopped by
   the agent), the key is free at once, not after the quiet time: a producer waiting beside it
   (held back, or claiming) puts its newest sample not yet put, if that is after the newest on
   the key (rule 1), and goes on. Of several producers alive beside it, the first by id does
   so; the others take it for the holder (rule 2).
6. **Take back.** A producer that gave the key away takes it back, by a claim as in rule 3,
   when it gets a lost input back, its estimate no less certain than the holder's: it was
   quiet for the longest quiet time (``QUIET_BOUNDS_S``), or its estimate suddenly became far
   more certain (covariance trace at most :data:`TAKE_BACK_RATIO` times its previous
   estimate's). The old derivation of a relation that lost a sensor is kept on standby
   (``agent.standby``), and the sensor's first measurement back does that, so the relation
   is served by it again within a sample, before the agent has even heard of the sensor. It
   does not take the key back merely because the holder became less certain than itself: a
   fusion on standby running on the camera alone and the camera-only flow holding the key
   would take it from each other in turn (the raw estimate's covariance jumps where the
   filter's does not), so a spare that took the key from a chosen flow about as certain, and
   then lost its own sensor, keeps it until the agent stops it. It does take it back, no less
   certain, when the holder has lost an input: :data:`HOLDER_LOST_IN_ROW` of the holder's
   samples in a row each at least ``1 / TAKE_BACK_RATIO`` times as uncertain as its least
   uncertain one of the last :data:`LOST_WINDOW_S` (a fusion of the better tracker and the
   camera, the better tracker gone, running on the camera alone beside the fusion of the
   A.R.T. tracker and the camera, which it took the key from; one degraded sample, a feature
   hidden, is not enough, and a holder merely less certain all along, the camera-only flow
   beside a fusion on standby running on the camera alone, keeps the key).
7. **A holder that lost an input gives the key up at once.** Each producer knows the providers
   and the measured edges it needs (``ComponentSpec.required_providers``, ``required_edges``:
   without one of them it computes nothing new) and watches their liveliness tokens: the
   provider's, and the one each edge's provider holds on the edge's data key while the edge
   delivers (``io.flowing``). When one is withdrawn while it holds the key and another
   producer of the key is alive, it stops putting and says so on the hand-over key, after
   which instant (``{"free": <producer>, "last": <ns>}``); the others take that as rule 5's
   holder gone, and the first by id puts its newest sample held back at once. The token
   goes within milliseconds of the provider leaving (its session closed, or its process gone
   and its links with it), and two and a half of the edge's intervals after its last sample
   when the sensor falls silent with its adapter running (judged at the adapter, which sees
   the sensor's own jitter only; in the second frame in a row without it when the adapter
   knows), while the key looks quiet to the others only three of the holder's intervals after
   its last put: in the switch bench the chain on the better tracker, kept on standby by the
   agent when the tracker left, held the key until it looked quiet, 68 ms
   (``docs/performance.md``, "A holder that lost a provider", "An edge that stops
   delivering"). A provider cut off without leaving (its machine's cable out) is still known
   by silence alone. The producer that gave the key up takes it back by rule 6, at once when
   the edge's token is back (its input is back) and its estimate no less certain than the
   holder's.

"Another producer is putting" means a sample not put by this one arrived within
:meth:`KeyHandOver.quiet_s`: three of the other's usual recent intervals, and one usual interval
longer than its longest recent one (bounded), or until the holder's token leaves (rule 5). With
the old producer gone (its sensor died) the key is quiet and the new one puts at once, its
covariance saying how good its first estimates are (issue [seamless], item 2). Each rule costs
O(1) per sample (the quiet time a sort of the eight intervals remembered, once a sample), plus
the decoding of every sample on the key by each producer watching it; a hand-over costs two
messages, and each producer one token, so O(producers) per key, and one liveliness subscriber
per provider and edge it needs (rule 7). The hand-over key's chunk is verbatim (``@``), so a
subscriber to the relation keys' wildcard does not receive the hand-over's messages nor its
tokens.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import threading
import time
import uuid
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from ubitrack_agent.core.codec import decode
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.core.measurements import WORKER, Measurement
from ubitrack_agent.net import logs
from ubitrack_agent.net.address import (
    is_misaddressed,
    put_addressed,
    reply_addressed,
    tag,
)
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.thread_pool import ThreadPool
from ubitrack_agent.net.transport import on_zenoh_thread

log = logging.getLogger("ubitrack.worker")

READY_RATIO = 1.0
"""A new producer's estimate is ready when its covariance's trace is at most this times the
current producer's latest (no less certain than what the application receives now)."""
WARM_S = 0.5
"""Nor before it has computed for this long, unless it is clearly more certain (rule 2): a
filter's first estimates claim a certainty its state has not earned. A fusion restored after
its process was killed, claiming the key back from its warm replica (``agent.spares``) at once,
put rotations beyond three sigma of their covariances in the switch benchmark
(``docs/performance.md``, "Replicas"); the agent keeps a replaced flow running for longer
than this (``HAND_OVER_HOLD_S``)."""
CLEARLY_RATIO = 0.5
"""A producer at most this times as uncertain as the holder claims without waiting
:data:`WARM_S`: a better flow is worth its first estimates (waiting, the demo's first fused
second kept the camera-only flow's 4 mm for half a second: ``docs/performance.md``,
"Replicas")."""
TAKE_BACK_RATIO = 0.1
"""A producer that gave the key away takes it back when its estimate's covariance trace drops
to at most this times its previous estimate's (rule 6): an input it had lost is back (the
tracker's data in a fusion that ran on the camera alone: about 430 to 8 mm^2 in the demo). A
flow that is merely better than the holder, by a better filter, say, does not take it."""
LOST_WINDOW_S = 2.0
"""The window of the holder's samples whose least uncertain one a sample is compared with to
read a lost input (rule 6): a filter that loses a sensor grows uncertain over tenths of a
second, not from one sample to the next."""
HOLDER_LOST_IN_ROW = 3
"""How many of the holder's samples in a row must each be at least ``1 / TAKE_BACK_RATIO``
times as uncertain as its least uncertain one of the last :data:`LOST_WINDOW_S` before a
producer that gave it the key takes it back (rule 6): a sensor lost stays lost for every
sample, a hidden feature spoils one (the switch benchmark's "better tracker leaves":
``docs/performance.md``, "The switch bench in session 22")."""
CLAIM_TIMEOUT_S = 0.25
"""How long a claimer waits for the holder's answer before it puts anyway (the key quiet) or
claims again (the holder still putting; rule 3)."""
QUIET_BOUNDS_S = (0.02, 0.5)
"""Bounds of the quiet time after which another producer counts as gone."""
QUIET_INTERVALS = 3.0
"""Another producer is gone after this many of its usual recent sample intervals
(:data:`USUAL_QUANTILE`) without a sample, and at least one usual interval longer than its
longest recent one (:meth:`KeyHandOver.quiet_s`)."""
USUAL_QUANTILE = 0.75
"""The quantile of the intervals between the other producer's recent timestamps taken as its
usual interval (:class:`_Intervals`): a fusion of a 60 Hz and a 30 Hz sensor puts samples 1 and
16 ms apart (its usual interval 16 ms, not 1), and one or two frames its sensor dropped do not
make it three times as long."""
INTERVALS_REMEMBERED = 8
"""How many of the other producer's latest sample intervals the quiet time is taken from."""
DEFAULT_QUIET_S = 0.1
"""The quiet time while the other producer's interval is not known yet (one sample seen)."""
MINE_REMEMBERED = 64
"""How many of its own puts' timestamps a producer remembers to tell them from the other's."""
MESSAGE_KINDS = {
    frozenset({"claim", "after"}): "claim",
    frozenset({"yield", "last", "to"}): "yield",
    frozenset({"yield", "last"}): "yield",
    frozenset({"holds"}): "holds",
    frozenset({"free", "last"}): "free",
}
"""A hand-over message's kind by its fields: a claim, the holder's answer, the holder's
reply to a producer starting (:meth:`KeyHandOver.holding`), or a holder giving the key up
(rule 7)."""
PUT = "SampleKind.PUT"
"""A token sample's kind when the token appeared (zenoh's ``SampleKind``, as text)."""
MAX_MESSAGE_BYTES = 256
"""A hand-over message is a small JSON object; a longer one is refused unread."""

COUNTERS = {
    "relation_not_after": "relation samples not put: not after the newest on the key",
    "relation_held": "relation samples not put: another producer puts, this estimate not ready",
    "relation_claiming": "relation samples not put: the key claimed, the holder's answer awaited",
    "relation_yielded": "relation samples not put: a newer producer claimed the key",
    "relation_taken": "times this producer took a relation key over from another one",
    "relation_taken_back": "times this producer took back a key it had given away (rule 6)",
    "relation_claims_unanswered": "claims that had no answer in time, the key quiet (put anyway)",
    "relation_claims_repeated": "claims said again: no answer in time, the holder still putting",
    "relation_holder_left": "times the producer holding a relation key left (its token gone)",
    "relation_given_up": "times this producer gave a relation key up: an edge it needs stopped",
    "relation_holder_gave_up": "times the producer holding a relation key gave it up (rule 7)",
    "relation_input_back": "times an input this producer gave a relation key up for came back",
    "relation_put_when_free": "relation samples held back, put when the key became free",
    "rejected_hand_over_messages": "hand-over messages refused (not a claim or an answer)",
}
"""The hand-over's counters, in the worker's status beside its own (``services.worker``)."""


def hand_over_key(relation_key: str) -> str:
    """The key of the hand-over messages of ``relation_key``."""
    return f"{relation_key}/@handover"


def producer_token(relation_key: str, producer: str) -> str:
    """The liveliness token of ``producer`` of ``relation_key`` (rule 5)."""
    return f"{hand_over_key(relation_key)}/{producer}"


def _instant(last: Any) -> int | None:
    """A message's ``last``: a timestamp (ns) or None; :class:`MessageError` otherwise."""
    if last is not None and (not isinstance(last, int) or isinstance(last, bool)):
        raise MessageError("malformed", "'last' is no timestamp")
    return last


def _trace(value: Measurement | None) -> tuple[tuple[int, ...], float] | None:
    covariance = getattr(value, "covariance", None)
    if covariance is None:
        return None
    matrix = np.asarray(covariance)
    return matrix.shape, float(np.trace(matrix))


class _Intervals:
    """Another producer's latest :data:`INTERVALS_REMEMBERED` intervals, between the arrivals of
    its samples and between their timestamps: the quiet time (:meth:`KeyHandOver.quiet_s`) takes
    the usual interval from the timestamps, the rate its sensors measure at, which a backlog
    delivered at once does not shorten (six samples of a 60 Hz chain put together after a
    stall would make the arrivals' usual interval a tenth of a millisecond), and the longest
    from the arrivals, the silences seen on the key. The two are worked out once per sample
    added, not per call (:meth:`KeyHandOver.quiet_s` runs on every sample seen and put)."""

    def __init__(self) -> None:
        self._arrivals: deque[float] = deque(maxlen=INTERVALS_REMEMBERED)
        self._stamps: deque[float] = deque(maxlen=INTERVALS_REMEMBERED)
        self._last_stamp_ns: int | None = None
        self._known: tuple[float, float] | None = None
        """:meth:`usual_and_longest` since the last change."""

    def __len__(self) -> int:
        return len(self._arrivals)

    def add(self, arrival_s: float | None, stamp_ns: int) -> None:
        """A sample stamped ``stamp_ns`` arrived ``arrival_s`` seconds after the one before
        (``None``: not an interval, the first after a silence or an answer): both intervals
        kept, the timestamps' if it is after the one before."""
        last, self._last_stamp_ns = self._last_stamp_ns, stamp_ns
        if arrival_s is None:
            return
        self._arrivals.append(arrival_s)
        if last is not None and stamp_ns > last:
            self._stamps.append((stamp_ns - last) / 1e9)
        self._known = None

    def clear(self) -> None:
        self._arrivals.clear()
        self._stamps.clear()
        self._last_stamp_ns = self._known = None

    def usual_and_longest(self) -> tuple[float, float]:
        """The :data:`USUAL_QUANTILE` of the timestamps' intervals (of the arrivals' while no
        timestamp interval is known), and the longest interval between arrivals; some interval
        must be known. O(intervals remembered) after a change, O(1) again until the next."""
        if self._known is None:
            intervals = sorted(self._stamps or self._arrivals)
            usual = intervals[math.ceil(USUAL_QUANTILE * len(intervals)) - 1]
            self._known = usual, max(self._arrivals)
        return self._known


class KeyHandOver:
    """The rules for one relation key of one producer: :meth:`admit` before each put;
    :meth:`observe` for each sample seen on the key, :meth:`receive` for each hand-over
    message, :meth:`joined` and :meth:`left` for the other producers' tokens (all on zenoh's
    thread); ``send`` puts a message on the hand-over key."""

    def __init__(
        self,
        key: str,
        counters: Counter[str],
        send: Callable[[bytes], None],
        clock: Callable[[], float] = time.monotonic,
        warm_s: float = WARM_S,
    ) -> None:
        self.key = key
        self.warm_s = warm_s
        """How long this producer computes before it may claim by rule 2 (:data:`WARM_S`)."""
        self.producer = uuid.uuid4().hex[:12]
        self._counters = counters
        self._send = send
        self._clock = clock
        self._lock = threading.RLock()
        """Re-entered where a put held back is made under it: zenoh may deliver the sample to
        this producer's own subscriber (:meth:`observe`) on the putting thread."""
        self._newest_ns: int | None = None
        self._mine: deque[int] = deque(maxlen=MINE_REMEMBERED)
        self._other_at: float | None = None
        """When another producer's latest sample arrived (monotonic)."""
        self._other_intervals = _Intervals()
        self._other_trace: tuple[tuple[int, ...], float] | None = None
        self._other_worse_in_row = 0
        """How many of the other producer's latest samples in a row were each at least ``1 /
        TAKE_BACK_RATIO`` times as uncertain as its least uncertain of the last
        :data:`LOST_WINDOW_S` (rule 6: it lost an input)."""
        self._other_least: deque[tuple[float, float]] = deque()
        """The other producer's (time, trace) of the last :data:`LOST_WINDOW_S`, increasing
        traces only: its first is the window's least (a sliding minimum, O(1) a sample)."""
        self._other_shape: tuple[int, ...] | None = None
        """The shape of the covariances in that window (traces of one shape compared only)."""
        self._claimed_at: float | None = None
        """When this producer claimed the key (monotonic), until answered or timed out."""
        self._holds = False
        """Whether this producer holds the key (puts on it)."""
        self._yielded = False
        """Whether this producer gave the key to a claimer that is still putting."""
        self._input_back = False
        """Whether, since it yielded, a measured edge it needs delivers again (rule 6)."""
        self._holder: str | None = None
        """The other producer that claimed the key last (holds it, as far as this one knows)."""
        self._alive: set[str] = set()
        """The other producers of the key whose tokens are up."""
        self.asking = False
        """Whether this producer's question who holds the key is still open (``Watch``): while
        it is, a quiet key may have a holder only late."""
        self._own_trace: tuple[tuple[int, ...], float] | None = None
        self._own_at: float | None = None
        """The covariance trace of this producer's latest estimate, and when it came (rule 6)."""
        self._first_at: float | None = None
        """When this producer's first estimate came (rule 2: :data:`WARM_S`)."""
        self._other_at_is_answer = False
        """Whether :attr:`_other_at` is when the key's latest sample was answered to this
        producer starting, not when the other producer put it (:meth:`observe_value`)."""
        self._watching_since = clock()
        """When this producer began to watch the key: a key it has seen nothing on is quiet
        only :data:`DEFAULT_QUIET_S` after this (rule 4)."""
        self._waiting: tuple[int, Callable[[], None]] | None = None
        """The newest sample held back (its timestamp and its put), put if the key becomes free
        before a newer one comes (rule 5)."""

    def quiet_s(self) -> float:
        """After how long without a sample another producer counts as gone: three of its usual
        recent intervals (:data:`USUAL_QUANTILE` of its timestamps', :class:`_Intervals`), and
        one usual interval longer than the longest recent silence between its samples'
        arrivals, so a silence as long as one seen lately (a hiccup of a loaded machine) is not
        taken for its end. Three of its *longest* intervals would let one frame its tracker
        dropped (2 % of a simulated A.R.T. tracker's frames) triple the wait for the next eight
        samples: in the switch bench the chain on the better tracker, which left, was claimed
        144 ms after its last sample, after a 42 ms interval (``docs/performance.md``, "The
        usual interval, not the longest"). O(1), the intervals sorted once per sample added
        (:class:`_Intervals`). A producer that gave the key to a claimer waits
        the longest until it knows :data:`INTERVALS_REMEMBERED` of the claimer's intervals (a
        new flow's first samples come unevenly, and taking the key back from it only late
        would hand the key to and fro); then as long as any other: a claimer on one sensor
        that stops is quiet at once (a chain on the better tracker, which left: the switch
        bench's 0.5 s gaps in session 23), and this producer claims the key back, which the
        claimer, if only late, answers before it puts again (rule 3)."""
        low, high = QUIET_BOUNDS_S
        if self._yielded and len(self._other_intervals) < INTERVALS_REMEMBERED:
            return high
        if not self._other_intervals:
            return DEFAULT_QUIET_S
        usual, longest = self._other_intervals.usual_and_longest()
        return min(high, max(low, QUIET_INTERVALS * usual, longest + usual))

    def observe(self, payload: bytes, latest: bool = False) -> None:
        """A sample seen on the key (:meth:`observe_value`); one that does not decode is the
        application's problem, not the hand-over's, and is ignored here."""
        try:
            value = decode(payload, level=WORKER)
        except MeasurementError:
            return
        self.observe_value(value, latest)

    def observe_value(self, value: Measurement, latest: bool = False) -> None:
        """A sample seen on the key, decoded: another producer's, or one of this producer's
        own puts (known by its timestamp, and then only the newest instant is noted).
        ``latest``: the key's latest sample, answered to this producer starting
        (:class:`Watch`): put at some time before, so the time to the holder's next sample is
        no interval of the holder's (taken for one, a 30 Hz holder's next sample 12 ms after
        the answer made the quiet time 38 ms, and the newcomer claimed the key at the holder's
        first slow frame); an answer coming after the holder's own samples is ignored."""
        now = self._clock()
        with self._lock:
            if self._newest_ns is None or value.timestamp_ns > self._newest_ns:
                self._newest_ns = value.timestamp_ns
            if value.timestamp_ns in self._mine:
                return
            if latest and self._other_at is not None:
                return  # the holder's samples came first: the answer tells nothing newer
            silence = None if self._other_at is None else now - self._other_at
            running = silence is not None and silence <= self.quiet_s()
            # A silence past the longest quiet time starts a new stream; a shorter one (a
            # hiccup, which may outlast the quiet time) is an interval like any other: the
            # quiet time grows by it, and a producer that gave the key away does not fall
            # back to waiting the longest (the switch bench's one 502 ms gap, session 30).
            if silence is None or silence > QUIET_BOUNDS_S[1]:
                self._other_intervals.clear()
                silence = None
            elif self._other_at_is_answer:
                silence = None
            self._other_intervals.add(silence, value.timestamp_ns)
            self._other_at, self._other_at_is_answer = now, latest
            self._other_trace = theirs = _trace(value)
            self._count_lost(now, theirs, running)

    def _count_lost(
        self, now: float, theirs: tuple[tuple[int, ...], float] | None, running: bool
    ) -> None:
        """Rule 6's count of the other producer's samples in a row that read a lost input;
        lock held."""
        least = self._other_least
        if theirs is None or not running or (least and self._other_shape != theirs[0]):
            least.clear()  # a new stream: nothing to compare with yet
        if theirs is None:
            self._other_worse_in_row = 0
            return
        self._other_shape = theirs[0]
        while least and least[0][0] < now - LOST_WINDOW_S:
            least.popleft()
        lost = bool(least) and least[0][1] <= TAKE_BACK_RATIO * theirs[1]
        self._other_worse_in_row = self._other_worse_in_row + 1 if lost else 0
        while least and least[-1][1] >= theirs[1]:
            least.pop()
        least.append((now, theirs[1]))

    def receive(self, payload: bytes) -> None:
        """A hand-over message: another producer's claim (answered at once if this one holds
        the key), the answer to this one's claim, or a holder's reply to this one starting.
        Anything else is refused and counted."""
        try:
            message = load_object(payload, MAX_MESSAGE_BYTES)
            kind = MESSAGE_KINDS.get(frozenset(message))
            sender = message.get(kind)
            if kind is None or not isinstance(sender, str):
                raise MessageError("malformed", "not a claim, an answer or a holder's reply")
            if sender == self.producer:
                return  # its own message, delivered to its own subscriber
            if kind == "claim":
                self._answer_claim(sender)
            elif kind == "holds":
                with self._lock:
                    self._holder = self._holder or sender
            elif kind == "free":
                self._freed(sender, _instant(message["last"]))
            else:
                self._take_answer(message)
        except MessageError as exc:
            logs.count_problem(
                self._counters, "rejected_hand_over_messages", log, "%s: %s", self.key, exc
            )

    def _answer_claim(self, claimer: str) -> None:
        """Another producer's claim: the holder yields to it and answers. A producer claiming
        the key itself when another claim comes, neither holding it (each taking the other
        for the holder, or the holder gone), keeps its claim if its id is the lower one and
        withdraws it otherwise (the lower one says its claim again, for the other to see
        after its own), so that only one takes the key when nobody answers."""
        with self._lock:
            if self._holds:
                self._holder = claimer
                self._holds, self._yielded, self._input_back = False, True, False
                # The claimer counts as putting from now: quiet from here means it died.
                self._other_at = self._clock()
                self._other_intervals.clear()
                message = {"yield": self.producer, "last": self._newest_ns, "to": claimer}
            elif self._claimed_at is not None and self.producer < claimer:
                # This claim stands: said again, for the other one to see and withdraw.
                message = {"claim": self.producer, "after": self._newest_ns}
            else:
                self._claimed_at, self._holder = None, claimer
                return  # not the holder: the holder answers
        self._send(json.dumps(message).encode())

    def _take_answer(self, message: dict[str, Any]) -> None:
        """The holder's answer to a claim: this producer takes the key if the answer is
        addressed to it (``to``), also a claim it has withdrawn since (the holder stopped for
        it); an answer without ``to`` (a producer before it was added) answers any claim. An
        answer to another producer's claim makes this one's void: that producer holds the key
        now, and this one claims it again from it if it is still ready (rule 2)."""
        last, to = _instant(message["last"]), message.get("to")
        if to is not None and not isinstance(to, str):
            raise MessageError("malformed", "an answer's 'to' is no producer")
        with self._lock:
            if to == self.producer:
                if not self._holds:
                    self._take(last)
                return
            if self._claimed_at is None:
                return  # an answer to another producer's claim
            if to is not None:
                self._claimed_at, self._holder, self._other_at = None, to, self._clock()
                self._other_intervals.clear()
                return
            self._take(last)

    def _take(self, after_ns: int | None) -> None:
        """Hold the key from now on, putting only what comes after ``after_ns``, and the sample
        held back last if it does; lock held."""
        self._claimed_at = None
        self._holds, self._yielded, self._holder = True, False, self.producer
        if after_ns is not None and (self._newest_ns is None or after_ns > self._newest_ns):
            self._newest_ns = after_ns
        waiting, self._waiting = self._waiting, None
        if waiting is not None and (self._newest_ns is None or waiting[0] > self._newest_ns):
            self._newest_ns = waiting[0]
            self._mine.append(waiting[0])
            self._counters["relation_put_when_free"] += 1
            waiting[1]()  # under the lock: before any later sample of this producer

    def joined(self, producer: str) -> None:
        """Another producer's token appeared (this one's own is ignored)."""
        if producer != self.producer:
            with self._lock:
                self._alive.add(producer)

    def left(self, producer: str) -> None:
        """Another producer's token left: if it held the key, the key is free now (rule 5),
        and a producer claiming it, or held back beside it, takes it with its newest sample.
        Of several producers left beside it (a flow on standby and a new one, say), only the
        first by id takes it so: the others count it as the holder, putting from now on, and
        go on by rule 2, so no two put one instant each."""
        with self._lock:
            self._alive.discard(producer)
            if producer != self._holder or producer == self.producer:
                return
            self._counters["relation_holder_left"] += 1
        self._holder_gone(producer, None)

    def _freed(self, producer: str, last_ns: int | None) -> None:
        """The holder gave the key up after ``last_ns`` (rule 7): free as if it had left
        (rule 5), but it stays alive, so it is nobody's successor. A message from a producer
        this one does not take for the holder (another holds it, as far as this one knows)
        changes nothing."""
        with self._lock:
            if producer == self.producer or self._holder not in (producer, None):
                return
            self._counters["relation_holder_gave_up"] += 1
        self._holder_gone(producer, last_ns)

    def _holder_gone(self, producer: str, last_ns: int | None) -> None:
        """The key's holder ``producer`` stopped putting after ``last_ns`` (None: not known):
        the first by id of the producers alive beside it takes the key, with its newest sample
        held back if it is after the newest on the key."""
        with self._lock:
            self._holder, self._other_at, self._yielded = None, None, False
            self._other_intervals.clear()
            successor = min((self._alive - {producer}) | {self.producer})
            if successor != self.producer:
                self._holder, self._other_at = successor, self._clock()
                self._claimed_at = None
                return
            taken = self._claimed_at is not None or self._waiting is not None
            if taken:
                self._take(last_ns)
            after = self._newest_ns
        if taken:  # the others waiting beside it, if any, yield
            self._claim(after)

    def input_stopped(self) -> None:
        """A measured edge this producer needs stopped delivering (rule 7): holding the key
        with another producer alive beside it, it stops putting and gives the key up, saying
        after which instant. The others count as putting from now on, so what it still
        computes (samples on their way when the edge stopped) is not put, and it takes the key
        back by rule 6, or after the longest quiet time if nobody takes it (an edge it did not
        really need)."""
        with self._lock:
            if not self._holds or not self._alive:
                return
            self._holds, self._yielded, self._holder = False, True, None
            self._input_back = False
            self._other_at = self._clock()
            self._other_intervals.clear()
            self._counters["relation_given_up"] += 1
            message = {"free": self.producer, "last": self._newest_ns}
        self._send(json.dumps(message).encode())

    def input_back(self) -> None:
        """A measured edge this producer needs delivers again: having yielded, it takes the key
        back by rule 6 with its next estimate no less certain than the holder's."""
        with self._lock:
            if self._yielded:
                self._input_back = True
                self._counters["relation_input_back"] += 1

    @property
    def holds(self) -> bool:
        """Whether this producer holds the key (puts on it)."""
        with self._lock:
            return self._holds

    def holding(self) -> bytes | None:
        """What this producer replies to one starting that asks who holds the key: itself, if
        it does (so a newcomer finding the key quiet claims it from a holder only late)."""
        with self._lock:
            holds = self._holds
        return json.dumps({"holds": self.producer}).encode() if holds else None

    def asked(self) -> None:
        """The question who holds the key is closed (its replies given to :meth:`receive`):
        with none alive and the key quiet, a claim awaiting an answer, or a sample held back,
        takes the key now."""
        with self._lock:
            self.asking = False
            quiet = self._other_at is None or self._clock() - self._other_at > self.quiet_s()
            held = self._claimed_at is not None or self._waiting is not None
            taken = held and quiet and not self._holder_alive()
            if taken:
                self._take(None)
            after = self._newest_ns
        if taken:
            self._claim(after)

    def _claim(self, after_ns: int | None) -> None:
        """Put a claim of the key, for what comes after ``after_ns``; lock not held."""
        self._send(json.dumps({"claim": self.producer, "after": after_ns}).encode())

    def _holder_alive(self) -> bool:
        """Whether another producer holds the key, as far as this one knows, and is alive;
        lock held."""
        return self._holder is not None and self._holder in self._alive

    def admit(self, value: Measurement | bytes, put: Callable[[], None] | None = None) -> bool:
        """Whether to put ``value`` (a relay's: its payload) on the key now; counted when
        not. ``put`` puts it: kept while the sample is held back, for the key becoming free
        before the next one (rule 5)."""
        if isinstance(value, bytes):
            try:
                value = decode(value, level=WORKER)
            except MeasurementError:
                return True  # checked where it came in; nothing here to judge it by
        now = self._clock()
        claim = wait = False
        with self._lock:
            other = self._other_at is not None and now - self._other_at <= self.quiet_s()
            if self._first_at is None:
                self._first_at = now
            previous = self._own_trace if self._own_at is not None else None
            if previous is not None and now - self._own_at > QUIET_BOUNDS_S[1]:
                previous = None  # quiet since: it lost its input and got it back
            self._own_trace, self._own_at = _trace(value), now
            if self._yielded and other:
                if not self._regained(previous):
                    return self._refuse("relation_yielded")
                self._yielded = False  # rule 6: its lost input is back
                self._claimed_at, claim, wait = now, True, True
                self._counters["relation_taken_back"] += 1
            elif self._claimed_at is not None and (other or self._holder_alive() or self.asking):
                # The answer awaited: the holder puts on, or is only late (it stops before
                # it answers, so nothing it puts comes after what this one puts then).
                if now - self._claimed_at < CLAIM_TIMEOUT_S:
                    return self._hold_back(value, put, "relation_claiming")
                if other:
                    # The holder puts on: its answer is late (a loaded machine) or the claim
                    # was lost. Putting now would put its instants twice: claim again, wait.
                    self._claimed_at, claim, wait = now, True, True
                    self._counters["relation_claims_repeated"] += 1
                else:
                    self._counters["relation_claims_unanswered"] += 1
                    self._take(None)
            elif not other and not self._holds:
                if (self._holder_alive() or self.asking) and self._starting(now):
                    # nothing seen on the key yet: the holder's next sample may be on its way
                    return self._hold_back(value, put, "relation_held")
                if self._holder_alive() or self.asking:  # maybe only late (a fusion waiting)
                    self._claimed_at, claim, wait = now, True, True
                    self._counters["relation_taken"] += 1
                else:  # nobody puts any more: at once, claiming the key all the same
                    self._take(None)
                    claim = True
            elif not self._holds:
                if not self._ready(value, now):
                    return self._hold_back(value, put, "relation_held")
                self._claimed_at, claim, wait = now, True, True
                self._counters["relation_taken"] += 1
            if wait:
                self._waiting = None if put is None else (value.timestamp_ns, put)
            admitted = wait or self._in_order(value)
            after = self._newest_ns
        if claim:
            self._claim(after)
        if wait:
            return self._refuse("relation_claiming")
        return admitted

    def _starting(self, now: float) -> bool:
        """Whether this producer has seen no sample of another on the key and has watched it
        for less than :data:`DEFAULT_QUIET_S`: a key is quiet after a quiet time *of watching*
        (rule 4). A flow started beside a holder putting at 30 Hz computes its first estimate
        within milliseconds, before the holder's next sample: claiming then took the key from
        a more certain holder (the holder yields to any claim): the camera-only chain took the
        key from the fusion running on the camera alone in 3 of 18 A.R.T.-off events of two
        switch-bench runs, 27-45 ms after its first estimate, and the application's error went
        from 5-6 to 9-12 mm RMS (``docs/performance.md``, "Who serves the camera-only phase");
        lock held."""
        return self._other_at is None and now - self._watching_since < DEFAULT_QUIET_S

    def _hold_back(self, value: Measurement, put: Callable[[], None] | None, counter: str) -> bool:
        """Refuse ``value`` for now, keeping its put for the key becoming free; lock held."""
        if put is not None:
            self._waiting = (value.timestamp_ns, put)
        return self._refuse(counter)

    def _in_order(self, value: Measurement) -> bool:
        """Rule 1, and the instant remembered as this producer's; lock held."""
        if self._newest_ns is not None and value.timestamp_ns <= self._newest_ns:
            return self._refuse("relation_not_after")
        self._newest_ns = value.timestamp_ns
        self._mine.append(value.timestamp_ns)
        return True

    def _ready(self, value: Measurement, now: float) -> bool:
        """Rule 2: clearly more certain than the holder, or no less certain and computing
        for :data:`WARM_S`; lock held."""
        mine, theirs = _trace(value), self._other_trace
        if mine is None or theirs is None or mine[0] != theirs[0]:
            return True  # nothing to compare: as good as can be told
        if mine[1] <= CLEARLY_RATIO * theirs[1]:
            return True
        warm = self._first_at is not None and now - self._first_at >= self.warm_s
        return warm and mine[1] <= READY_RATIO * theirs[1]

    def _regained(self, previous: tuple[tuple[int, ...], float] | None) -> bool:
        """Rule 6: this producer's latest estimate is no less certain than the holder's latest
        sample, and the holder has lost an input (:data:`HOLDER_LOST_IN_ROW` samples in a row
        each ten times as uncertain as its least uncertain one of the last
        :data:`LOST_WINDOW_S`) or this producer has got one back: an edge it needs delivers
        again (:meth:`input_back`), it was quiet (``previous`` is None) or its estimate is at
        most :data:`TAKE_BACK_RATIO` times as uncertain as its
        ``previous`` one (covariances of one shape); lock held."""
        mine, theirs = self._own_trace, self._other_trace
        if mine is None or theirs is None or mine[0] != theirs[0]:
            return False
        if mine[1] > READY_RATIO * theirs[1]:
            return False
        if self._other_worse_in_row >= HOLDER_LOST_IN_ROW or self._input_back:
            return True
        if previous is None:
            return True
        return previous[0] == mine[0] and mine[1] <= TAKE_BACK_RATIO * previous[1]

    def _refuse(self, counter: str) -> bool:
        self._counters[counter] += 1
        return False


HAND_OVER = ThreadPool("hand-over", 1)
"""The one thread of the process that runs what every :class:`Watch` sees on its relation key
and its hand-over key, in the order zenoh delivered it (one thread: a claim and its answer are
never reordered). Handed on from zenoh's own thread (``net.transport.on_zenoh_thread``), so a
watch starts no thread of its own: before, zenoh-python started one per subscriber, two per
relation key a component puts on, four with the token subscriber and the queryable
(``docs/performance.md``, "Threads of a container"). Not
zenoh's thread itself: :meth:`KeyHandOver.receive` may put an answer (a zenoh call) and waits
for the rules' lock. Started on the first sample, then kept (``net.thread_pool``)."""


def _handed_on(
    call: Callable[[Any], None], finished: Callable[[], None] | None = None
) -> zenoh.handlers.Callback:
    """A handler on zenoh's thread that hands what zenoh delivers (a sample, a query, a reply)
    to ``call`` on :data:`HAND_OVER` (a queue's put), and ``finished`` (a query's end, after
    its replies: zenoh drops the handler after the last) behind them. While the interpreter
    ends no thread starts, and it is dropped."""

    def hand_on(delivered: Any) -> None:
        # RuntimeError: "can't create new thread at interpreter shutdown"
        with contextlib.suppress(RuntimeError):
            HAND_OVER.submit(call, delivered)

    if finished is None:
        return on_zenoh_thread(hand_on)

    def drop() -> None:
        with contextlib.suppress(RuntimeError):
            HAND_OVER.submit(lambda _: finished(), None)

    return zenoh.handlers.Callback(hand_on, drop, indirect=False)


_PRODUCERS_HERE: dict[tuple[int, str], tuple[Watch, ...]] = {}
"""The watches of this process by session (its ``id``: a watch keeps its session) and relation
key: the other producers of a key on the session, which see a producer's puts from it
(:meth:`Watch.put`), not from zenoh."""
_PRODUCERS_LOCK = threading.Lock()


class Watch:
    """A :class:`KeyHandOver` wired to zenoh: subscribed to its relation key, its hand-over key
    and the producers' tokens, putting its messages on the hand-over key and declaring its own
    token. Undeclare with :meth:`close`. Its subscribers, its queryable and its two queries
    hand what they get to :data:`HAND_OVER` (O(1) each; no thread per watch: a query given a
    plain callable had zenoh-python start a thread for its replies, and the start waits for
    the new thread to take Python's lock, 2-17 ms each in a busy container of 80-100
    components, ``docs/performance.md``, "First sample for 100 applications, session 21").

    Its subscriber to the relation key takes the samples of other processes only
    (``Locality.REMOTE``): zenoh delivers a session's own puts to its own subscribers, and
    this producer's own samples, which teach its rules nothing (:meth:`KeyHandOver.observe_value`),
    cost each sample a call on zenoh's thread, a wake of :data:`HAND_OVER` and a decoding
    (about a fifth of a container's Python time at 5,000 samples/s,
    ``docs/performance.md``, "Throughput, session 22"). The other producers of the key in
    this process are shown its samples by :meth:`put` instead."""

    def __init__(
        self, session: Any, key: str, counters: Counter[str], needed: tuple[str, ...] = ()
    ) -> None:
        """``needed``: the liveliness tokens of the providers and the measured edges this
        producer needs (rule 7), a subscriber each."""
        messages = hand_over_key(key)
        self.rules = KeyHandOver(key, counters, lambda data: put_addressed(session, messages, data))
        self._key_tag, self._messages_tag = tag(key), tag(messages)
        self._counters = counters
        self._observe_here = logs.guarded(self._observe_value, counters, log, key)
        """:meth:`_observe_value` made total (``internal_errors``)."""
        liveliness = session.liveliness()
        self._here = (id(session), key)
        with _PRODUCERS_LOCK:
            _PRODUCERS_HERE[self._here] = (*_PRODUCERS_HERE.get(self._here, ()), self)
        self._subscribers = (
            session.declare_subscriber(
                key, self._handed_on(self._observe), allowed_origin=zenoh.Locality.REMOTE
            ),
            session.declare_subscriber(messages, self._handed_on(self._receive)),
            liveliness.declare_subscriber(
                producer_token(key, "*"), self._handed_on(self._token), history=True
            ),
            liveliness.declare_token(producer_token(key, self.rules.producer)),
            session.declare_queryable(messages, self._handed_on(self._holding)),
            *(
                liveliness.declare_subscriber(edge, self._handed_on(self._needed_edge))
                for edge in needed
            ),
        )
        self.rules.asking = True  # who holds the key, if one does
        session.get(
            messages,
            self._handed_on(self._holder, self.rules.asked),
            timeout=CLAIM_TIMEOUT_S,
        )
        # The holder's latest sample, if one holds the key (its queryable answers it): seen
        # before this producer's first output, however late the holder's next sample comes.
        session.get(key, self._handed_on(self._latest))

    def _handed_on(
        self, handler: Callable[[Any], None], finished: Callable[[], None] | None = None
    ) -> zenoh.handlers.Callback:
        key = self.rules.key
        done = None if finished is None else logs.guarded(finished, self._counters, log, key)
        return _handed_on(logs.guarded(handler, self._counters, log, key), done)

    def put(self, publish: Callable[[bytes], None], payload: bytes, value: Any) -> None:
        """Put ``payload`` by ``publish`` and show ``value`` (its measurement, or the payload
        itself as it is) to the other producers of the key on this session,
        on :data:`HAND_OVER` as zenoh's samples are (none is shown one on the putting thread:
        two producers putting held-back samples under their rules' locks would wait for each
        other's). O(producers of the key in the process), one in the common case."""
        publish(payload)
        others = _PRODUCERS_HERE.get(self._here, ())
        if len(others) > 1:
            for other in others:
                if other is not self:
                    with contextlib.suppress(RuntimeError):  # the interpreter ends
                        HAND_OVER.submit(other._observe_here, value)

    def _observe_value(self, value: Any) -> None:
        """On :data:`HAND_OVER`: a sample another producer of this process put."""
        if isinstance(value, bytes):
            self.rules.observe(value)
        else:
            self.rules.observe_value(value)

    def _observe(self, sample: Any) -> None:
        if is_misaddressed(sample, self._key_tag):
            self._counters["misaddressed"] += 1  # zenoh delivered it here: net.address
            return
        self.rules.observe(sample.payload.to_bytes())

    def _receive(self, sample: Any) -> None:
        if is_misaddressed(sample, self._messages_tag):
            self._counters["misaddressed"] += 1
            return
        self.rules.receive(sample.payload.to_bytes())

    def _token(self, sample: Any) -> None:
        producer = str(sample.key_expr).rsplit("/", 1)[-1]
        if str(sample.kind) == PUT:
            self.rules.joined(producer)
        else:
            self.rules.left(producer)

    def _needed_edge(self, sample: Any) -> None:
        if str(sample.kind) == PUT:
            self.rules.input_back()
        else:
            self.rules.input_stopped()

    def _holding(self, query: Any) -> None:
        with query:  # finished at once (zenoh sends its final message when it is dropped)
            reply = self.rules.holding()
            if reply is not None:
                reply_addressed(query, hand_over_key(self.rules.key), reply, JSON)

    def _holder(self, reply: Any) -> None:
        if reply.ok is not None and not is_misaddressed(reply.ok):
            self.rules.receive(reply.ok.payload.to_bytes())

    def _latest(self, reply: Any) -> None:
        if reply.ok is not None and not is_misaddressed(reply.ok):
            self.rules.observe(reply.ok.payload.to_bytes(), latest=True)

    def close(self) -> None:
        with _PRODUCERS_LOCK:
            others = tuple(w for w in _PRODUCERS_HERE.pop(self._here, ()) if w is not self)
            if others:
                _PRODUCERS_HERE[self._here] = others
        for subscriber in self._subscribers:
            subscriber.undeclare()

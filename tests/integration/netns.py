"""Network namespaces for multi-host integration tests: each "machine" is a namespace of its
own, wired to one or more switches (LANs), and its processes run in it with ``ip netns exec``.

Nothing touches the root namespace: each LAN is a bridge in a "switch" namespace of its own,
and every machine's cable is a veth pair from that bridge to the machine (``eth0`` on the
first LAN it is on, ``eth1`` on the second, ...). A machine on several LANs (a zenoh router
between two sites) has no route between them: it forwards nothing, so the router process is
the only path. Addresses are ``10.<k>.0.<n>/24`` with ``k`` drawn per LAN and run, and names
start with ``ubt`` and six random hex digits, so concurrent runs never meet (a run's addresses
exist only inside its own namespaces anyway). Loopback is up in every machine.

:class:`Network` is a context manager (also registered with ``atexit``) that ends every
process it started, kills whatever else still runs in its namespaces (such as workers a host
manager started) and deletes the namespaces, with them the veths and bridges, pass or fail.
:func:`netns` is the pytest fixture: a factory of networks, deleted when the module's tests
end, skipping the test with the reason printed when namespaces are not available (not root,
no ``ip``, or ``ip netns add`` refused, say in a container without ``CAP_SYS_ADMIN``).
"""

from __future__ import annotations

import atexit
import contextlib
import os
import secrets
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

PROCESS_EXIT_S = 5.0
"""How long a process may take to end after SIGTERM before it is killed."""


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be made here; the message says why."""


def _ip(*arguments: str) -> None:
    """Run ``ip`` with ``arguments``; :class:`NetnsUnavailable` with its error if it fails."""
    result = subprocess.run(["ip", *arguments], capture_output=True, text=True)
    if result.returncode != 0:
        raise NetnsUnavailable(f"ip {' '.join(arguments)}: {result.stderr.strip()}")


def unavailable_reason() -> str | None:
    """Why namespaces cannot be used here, or None if they can (as far as can be told without
    making one)."""
    if os.geteuid() != 0:
        return "network namespaces need root (CI runs as root)"
    if shutil.which("ip") is None:
        return "network namespaces need the ip command (iproute2)"
    return None


@dataclass
class Machine:
    """One namespace: its name in ``ip netns`` and its address on each LAN."""

    namespace: str
    addresses: dict[str, str] = field(default_factory=dict)
    """LAN name -> IPv4 address."""
    interfaces: dict[str, str] = field(default_factory=dict)
    """LAN name -> the switch-side end of its cable, in the LAN's switch namespace."""

    @property
    def address(self) -> str:
        """Its address on its first LAN."""
        return next(iter(self.addresses.values()))


class Network:
    """Machines (namespaces) wired to LANs (bridges in switch namespaces).

    ``lans`` maps each LAN's name to the machines on it, e.g. ``{"site": ["router", "room",
    "hmd"]}``; a machine listed on several LANs gets one interface on each."""

    def __init__(self, lans: Mapping[str, Sequence[str]], log_dir: Path | None = None) -> None:
        self.tag = f"ubt{secrets.token_hex(3)}"
        self.log_dir = Path(log_dir or tempfile.mkdtemp(prefix=f"{self.tag}-"))
        self.machines: dict[str, Machine] = {}
        self.switches: dict[str, str] = {}
        self.processes: dict[str, subprocess.Popen] = {}
        self._namespaces: list[str] = []
        atexit.register(self.close)
        try:
            self._build(lans)
        except BaseException:
            self.close()
            raise

    def _add_namespace(self, name: str) -> str:
        namespace = f"{self.tag}-{name}"
        _ip("netns", "add", namespace)
        self._namespaces.append(namespace)
        _ip("-n", namespace, "link", "set", "lo", "up")
        return namespace

    def _build(self, lans: Mapping[str, Sequence[str]]) -> None:
        subnets = secrets.SystemRandom().sample(range(16, 255), len(lans))
        for (lan, members), subnet in zip(lans.items(), subnets, strict=True):
            switch = self.switches[lan] = self._add_namespace(f"sw-{lan}")
            _ip("-n", switch, "link", "add", "br0", "type", "bridge")
            _ip("-n", switch, "link", "set", "br0", "up")
            for host, name in enumerate(members, start=1):
                machine = self.machines.get(name)
                if machine is None:
                    machine = self.machines[name] = Machine(self._add_namespace(name))
                port, interface = f"p{host}", f"eth{len(machine.addresses)}"
                _ip("-n", switch, "link", "add", port, "type", "veth", "peer", "name", interface)
                _ip("-n", switch, "link", "set", interface, "netns", machine.namespace)
                _ip("-n", switch, "link", "set", port, "master", "br0", "up")
                address = f"10.{subnet}.0.{host}"
                _ip("-n", machine.namespace, "addr", "add", f"{address}/24", "dev", interface)
                _ip("-n", machine.namespace, "link", "set", interface, "up")
                machine.addresses[lan] = address
                machine.interfaces[lan] = port

    # -- processes --------------------------------------------------------------------------

    def spawn(
        self, machine: str, argv: Sequence[str], name: str, pipes: bool = False
    ) -> subprocess.Popen:
        """Run ``argv`` on ``machine`` in a process group of its own, its output going to the
        log file :meth:`log` reads (``name`` names it there); with ``pipes``, its standard input
        and output are text pipes instead (its standard error still goes to the log)."""
        if name in self.processes and self.processes[name].poll() is None:
            raise ValueError(f"a process named {name!r} still runs")
        log = (self.log_dir / f"{name}.log").open("ab")
        try:
            process = subprocess.Popen(
                ["ip", "netns", "exec", self.machines[machine].namespace, *argv],
                stdin=subprocess.PIPE if pipes else subprocess.DEVNULL,
                stdout=subprocess.PIPE if pipes else log,
                stderr=log,
                text=pipes,
                start_new_session=True,
            )
        finally:
            log.close()
        self.processes[name] = process
        return process

    def log(self, name: str, lines: int = 30) -> str:
        """The last ``lines`` lines of process ``name``'s output."""
        path = self.log_dir / f"{name}.log"
        text = path.read_text(errors="replace") if path.exists() else "(no output)"
        return "\n".join(text.splitlines()[-lines:])

    def logs(self, *names: str, lines: int = 30) -> str:
        """The tails of the named processes' logs (default: all), for a failure message."""
        return "\n".join(
            f"--- {name} (tail) ---\n{self.log(name, lines)}" for name in names or self.processes
        )

    def pids(self, machine: str) -> set[int]:
        """Every process running on ``machine`` (``ip netns pids``)."""
        return _pids(self.machines[machine].namespace)

    def kill_all(self, machine: str, keep: Sequence[int] = ()) -> set[int]:
        """SIGKILL every process on ``machine`` but ``keep``: the machine fails; the killed."""
        killed = self.pids(machine) - set(keep)
        for pid in killed:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        return killed

    # -- cables -----------------------------------------------------------------------------

    def link_down(self, machine: str) -> None:
        """Pull ``machine``'s cables out of their switches: its processes see no error, only
        silence (as when a cable is cut), until :meth:`link_up`."""
        self._set_links(machine, "down")

    def link_up(self, machine: str) -> None:
        """Plug ``machine``'s cables back in."""
        self._set_links(machine, "up")

    def _set_links(self, machine: str, state: str) -> None:
        for lan, port in self.machines[machine].interfaces.items():
            _ip("-n", self.switches[lan], "link", "set", port, state)

    # -- clean-up ---------------------------------------------------------------------------

    def close(self) -> None:
        """End every process, then delete every namespace (twice is harmless)."""
        for process in self.processes.values():
            _end_group(process)
            for pipe in (process.stdin, process.stdout):
                if pipe is not None:
                    pipe.close()
        for namespace in self._namespaces:
            for pid in _pids(namespace):  # what the processes started, and left behind
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        for namespace in reversed(self._namespaces):
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True)
        self._namespaces.clear()
        atexit.unregister(self.close)

    def __enter__(self) -> Network:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _pids(namespace: str) -> set[int]:
    result = subprocess.run(["ip", "netns", "pids", namespace], capture_output=True, text=True)
    return {int(pid) for pid in result.stdout.split()}


def _end_group(process: subprocess.Popen) -> None:
    """End ``process``'s group: SIGTERM, then SIGKILL after :data:`PROCESS_EXIT_S`."""
    if process.poll() is not None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)  # what it left in its group
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    try:
        process.wait(timeout=PROCESS_EXIT_S)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


@pytest.fixture(scope="module")
def netns(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[..., Network]]:
    """A factory ``netns(lans) -> Network``; every network it made is deleted when the module's
    tests end, pass or fail. Skips (reason printed with ``-ra``) where namespaces cannot be
    made."""
    if reason := unavailable_reason():
        pytest.skip(reason)
    made: list[Network] = []
    # SIGTERM (a CI time-out, say) ends the tests through this fixture's clean-up too.
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm)

    def make(lans: Mapping[str, Sequence[str]]) -> Network:
        try:
            network = Network(lans, tmp_path_factory.mktemp("netns"))
        except NetnsUnavailable as exc:
            pytest.skip(f"network namespaces unavailable: {exc}")
        made.append(network)
        return network

    try:
        yield make
    finally:
        for network in made:
            network.close()
        signal.signal(signal.SIGTERM, previous)


def _exit_on_sigterm(*_: object) -> None:
    raise KeyboardInterrupt("SIGTERM")  # pytest stops, and runs the clean-up on its way out

"""``ubitrack agent`` gives its own host manager the capacity options of ``ubitrack host``,
leaves it serving on a clean stop unless asked, and uses the host manager of its machine's
name that serves when its own gave way."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from ubitrack_agent.cli import build_parser
from ubitrack_agent.commands import agent as agent_command
from ubitrack_agent.commands.agent import HostOptions, HostWhileActive
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import DEFAULT_CAPACITY, MAX_CAPACITY, MAX_CORES
from ubitrack_agent.services.host import build_parser as host_parser


def agent_options(*argv: str) -> HostOptions:
    args = build_parser().parse_args(["agent", *argv])
    return HostOptions.of(args)


def test_the_options_reach_the_host_manager_as_its_own_flags():
    argv = ("--labels", "gpu,camera", "--capacity", "3", "--pool-size", "1", "--workers-as-peers")
    options = agent_options(*argv, "--cores", "4", "--isolate")
    assert options == HostOptions(
        1, frozenset({"camera", "gpu"}), 3, workers_as_peers=True, cores=4, isolate=True
    )
    host = host_parser().parse_args(options.flags())  # what the embedded host manager is given
    given = (host.pool_size, host.labels, host.capacity, host.workers_as_peers)
    assert given == (1, frozenset({"camera", "gpu"}), 3, True)
    assert (host.cores, host.isolate) == (4, True)
    assert options.problem() is None


def test_the_defaults_are_the_host_managers():
    options = agent_options()
    host = host_parser().parse_args(options.flags())
    assert host == host_parser().parse_args([])  # the flags given change no default
    assert not options.workers_as_peers  # worker processes are the host manager's clients
    assert options.capacity == DEFAULT_CAPACITY and "--labels" not in options.flags()
    assert options.cores is None and not options.isolate


@pytest.mark.parametrize(
    ("argv", "problem"),
    [
        (["--capacity", "0"], "--capacity must be 1 to"),
        (["--capacity", str(MAX_CAPACITY + 1)], "--capacity must be 1 to"),
        (["--pool-size", "-1"], "--pool-size must be >= 0"),
        (["--cores", "0"], "--cores must be 1 to"),
        (["--cores", str(MAX_CORES + 1)], "--cores must be 1 to"),
    ],
)
def test_invalid_capacities_are_refused(argv, problem):
    assert problem in agent_options(*argv).problem()


def test_invalid_labels_are_refused_by_the_parser():
    with pytest.raises(SystemExit):
        agent_options("--labels", "a b")


def test_a_clean_stop_leaves_the_host_manager_serving_unless_asked():
    assert not build_parser().parse_args(["agent"]).stop_host_on_exit
    assert build_parser().parse_args(["agent", "--stop-host-on-exit"]).stop_host_on_exit


def test_an_agent_whose_host_manager_gave_way_uses_the_one_serving(monkeypatch):
    """Its host manager exited because another of its name came first (``NAME_TAKEN``): the
    agent starts none while that one serves, and starts its own again once none does."""
    started: list[SimpleNamespace] = []

    def embedded(*_options):
        started.append(SimpleNamespace(gave_way=False, stop_restarting=lambda: None))
        return started[-1]

    monkeypatch.setattr(agent_command, "EmbeddedHost", embedded)
    host = HostWhileActive(config.Settings(), HostOptions(), "INFO")
    serving = [False]
    host.serving = lambda: serving[0]
    host.on_role(True)
    assert len(started) == 1
    started[0].gave_way, serving[0] = True, True  # exited with NAME_TAKEN; the other serves
    host.on_role(True)
    assert len(started) == 1 and host.host is None
    serving[0] = False  # the other one is gone
    host.on_role(True)
    assert len(started) == 2 and host.host is started[1]
    host.stop_restarting()

"""``ubitrack agent`` gives its own host manager the capacity options of ``ubitrack host``."""

from __future__ import annotations

import pytest

from ubitrack_agent.cli import build_parser
from ubitrack_agent.commands.agent import HostOptions
from ubitrack_agent.net.host_protocol import DEFAULT_CAPACITY, MAX_CAPACITY
from ubitrack_agent.services.host import build_parser as host_parser


def agent_options(*argv: str) -> HostOptions:
    args = build_parser().parse_args(["agent", *argv])
    return HostOptions(args.pool_size, args.labels, args.capacity, args.workers_as_peers)


def test_the_options_reach_the_host_manager_as_its_own_flags():
    argv = ("--labels", "gpu,camera", "--capacity", "3", "--pool-size", "1", "--workers-as-peers")
    options = agent_options(*argv)
    assert options == HostOptions(1, frozenset({"camera", "gpu"}), 3, workers_as_peers=True)
    host = host_parser().parse_args(options.flags())  # what the embedded host manager is given
    given = (host.pool_size, host.labels, host.capacity, host.workers_as_peers)
    assert given == (1, frozenset({"camera", "gpu"}), 3, True)
    assert options.problem() is None


def test_the_defaults_are_the_host_managers():
    options = agent_options()
    host = host_parser().parse_args([])
    assert options == HostOptions(host.pool_size, host.labels, host.capacity, host.workers_as_peers)
    assert not options.workers_as_peers  # worker processes are the host manager's clients
    assert options.capacity == DEFAULT_CAPACITY and "--labels" not in options.flags()


@pytest.mark.parametrize(
    ("argv", "problem"),
    [
        (["--capacity", "0"], "--capacity must be 1 to"),
        (["--capacity", str(MAX_CAPACITY + 1)], "--capacity must be 1 to"),
        (["--pool-size", "-1"], "--pool-size must be >= 0"),
    ],
)
def test_invalid_capacities_are_refused(argv, problem):
    assert problem in agent_options(*argv).problem()


def test_invalid_labels_are_refused_by_the_parser():
    with pytest.raises(SystemExit):
        agent_options("--labels", "a b")

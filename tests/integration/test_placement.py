"""Placement on loopback, with real processes (``ubitrack_agent/agent/placement.py``): host
managers named as machines, a tracker and an application on one of them. The components go
beside their data, move when that host vanishes with its workers, and come back when it
returns. ``tests/integration/test_hosts_netns.py`` does the same across network namespaces."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.test_host import Network, network
from tests.integration.zenoh_helpers import member_flags, wait_until
from ubitrack_agent.graph.templates import shipped_templates
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import RelationId

pytestmark = pytest.mark.integration

WT_HT = RelationId("WT", "HT", "6D")
WITHOUT_OPENCV = (
    "-c",
    "import sys; sys.modules.update(cv2=None, scipy=None); "  # importing either now fails
    "from ubitrack_agent.cli import main; sys.exit(main())",
)
"""Runs the CLI as on a small machine without OpenCV and SciPy: the agent needs neither."""


@pytest.fixture
def net(processes) -> Iterator[Network]:
    yield from network(processes, as_hub=False)


def hosts_of_components(net: Network) -> dict[str, str | None]:
    status = net.agent_status() or {}
    return {instance: c["host"] for instance, c in status.get("components", {}).items()}


def test_components_run_beside_their_data_move_with_their_host_and_come_back(net):
    net.agent("--no-host", entry=WITHOUT_OPENCV)
    # "alpha" sorts first: before placement, every worker went to the first host by name.
    net.host("alpha", 2)
    room = net.host("room", 2)
    net.tracker(host_name="room")
    relation = Relation(net.session, net.keys, WT_HT, application="app", host="room")
    wait_until(lambda: relation.latest() is not None, timeout=30)
    placed = hosts_of_components(net)
    assert placed and set(placed.values()) == {"room"}, placed
    status = net.agent_status()
    assert status["application_hosts"] == {str(WT_HT): ["room"]}
    assert set(status["host_info"]) == {"alpha", "room"}
    command = [sys.executable, "-m", "ubitrack_agent.cli", "status"]
    shown = subprocess.run(
        [*command, *member_flags(net.port, net.domain)], capture_output=True, text=True, timeout=60
    ).stdout
    assert "host room: capacity" in shown and f"query {WT_HT} from app on room" in shown
    assert shown.count(", alive on room in room-") == len(placed), shown  # and its container

    # The room's machine fails: its host manager and its workers (one process group) die.
    os.killpg(room.pid, signal.SIGKILL)
    wait_until(lambda: set(hosts_of_components(net).values()) == {"alpha"}, timeout=30)
    before = relation.received
    wait_until(lambda: relation.received > before + 10, timeout=30)  # flowing again

    # It returns: the component reading the tracker's stream and publishing to the application
    # moves back (it saves two crossings); the inversion of the static ART->WT stays (it
    # would save a static input only, less than the margin). The old process is stopped.
    net.host("room", 2)
    status = net.agent_status()
    (producer,) = [i for i, c in status["components"].items() if c["relations"]]
    wait_until(lambda: hosts_of_components(net)[producer] == "room", timeout=30)
    wait_until(lambda: producer not in net.status("alpha")["instances"], timeout=30)
    assert set(net.status("alpha")["instances"]) == set(placed) - {producer}
    assert net.agent_status()["counters"]["moves"] == 1
    before = relation.received
    wait_until(lambda: relation.received > before + 10, timeout=30)
    relation.close()


def test_a_query_may_require_labels_of_the_host_running_its_last_hop(net):
    net.agent("--no-host")
    net.host("room", 2)
    net.host("screen", 2, "-m", "ubitrack_agent.services.host", "--labels", "display,gpu")
    net.tracker(host_name="room")
    relation = Relation(
        net.session, net.keys, WT_HT, application="app", host="room", host_labels={"display"}
    )
    wait_until(lambda: relation.latest() is not None, timeout=30)
    status = net.agent_status()
    (producer,) = [i for i, c in status["components"].items() if c["relations"]]
    placed = hosts_of_components(net)
    assert placed[producer] == "screen", placed  # the label, though the data is in the room
    assert set(placed.values()) == {"room", "screen"}, placed  # the rest beside the tracker
    assert status["host_info"]["screen"]["labels"] == ["display", "gpu"]
    relation.close()

    # Nobody has the label: the producer waits, and the status says why.
    with Relation(
        net.session, net.keys, WT_HT, application="app2", host="room", host_labels={"vr"}
    ):
        wait_until(lambda: net.agent_status()["unplaced"], timeout=30)
        (reason,) = set(net.agent_status()["unplaced"].values())
        assert reason == "no live host manager has the labels vr"


# -- isolation: a container of its own (docs/architecture.md, "Containers") -------------------


def containers_of(net: Network, relation: Relation) -> dict[str, tuple[str, int]]:
    """Each component's container and process, once the relation flows and every component
    runs (the agent's status)."""

    def placed() -> dict[str, tuple[str, int]] | None:
        components = (net.agent_status() or {}).get("components", {})
        where = {i: (c["container"], c["pid"]) for i, c in components.items() if c["alive"]}
        done = components and len(where) == len(components) and all(p for _, p in where.values())
        return where if done and relation.latest() is not None else None

    return wait_until(placed, timeout=30)


def isolating_templates(directory: Path) -> Path:
    """The shipped templates, the inversion's asking for a container of its own."""
    directory.mkdir()
    for entry in shipped_templates().iterdir():
        if entry.name.endswith(".yaml"):
            text = entry.read_text(encoding="utf-8")
            extra = "isolation: own\n" if entry.name == "inversion.yaml" else ""
            (directory / entry.name).write_text(text + extra)
    return directory


def test_a_template_asking_for_isolation_runs_in_a_container_process_of_its_own(net, tmp_path):
    """``isolation: own`` in the inversion's template: the flow's inversion (of the static
    ART->WT) runs alone in ``room-<instance>``, a process of its own; the concatenation reading
    it runs in the host's shared container ``room-0`` and reads it over zenoh."""
    templates = isolating_templates(tmp_path / "templates")
    net.agent("--no-host", "--templates", str(templates))
    net.host("room", 2, "-m", "ubitrack_agent.services.host", "--cores", "1")
    net.tracker(host_name="room")
    with Relation(net.session, net.keys, WT_HT, application="app", host="room") as relation:
        where = containers_of(net, relation)
        services = {i: c["service"] for i, c in net.agent_status()["components"].items()}
        (inversion,) = [i for i, service in services.items() if service == "inversion"]
        (concatenation,) = [i for i, service in services.items() if service == "concatenation"]
        assert where[inversion][0] == f"room-{inversion}", where
        assert where[concatenation][0] == "room-0", where
        assert where[inversion][1] != where[concatenation][1], where  # two processes
        assert set(net.status("room")["instances"]) == {inversion, concatenation}
        before = relation.received
        wait_until(lambda: relation.received > before + 10, timeout=30)


def test_a_host_asking_for_isolation_runs_each_component_in_a_process_of_its_own(net):
    """``ubitrack host --isolate``: every component of the host alone in a container."""
    net.agent("--no-host")
    net.host("room", 2, "-m", "ubitrack_agent.services.host", "--isolate")
    net.tracker(host_name="room")
    with Relation(net.session, net.keys, WT_HT, application="app", host="room") as relation:
        where = containers_of(net, relation)
        assert len(where) == 2 and {c for c, _ in where.values()} == {
            f"room-{instance}" for instance in where
        }, where
        assert len({pid for _, pid in where.values()}) == 2, where
        assert net.agent_status()["host_info"]["room"]["isolating"] is True

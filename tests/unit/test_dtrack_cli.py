"""``ubitrack dtrack`` stands on its own: documented defaults for a real A.R.T. system, a clear
error without a body mapping, no simulator loaded; the demo passes its scenario's mapping."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ubitrack_agent.cli import build_parser
from ubitrack_agent.commands.demo import dtrack_flags
from ubitrack_agent.sim_trackers.scenario import load_scenario


def test_defaults_are_those_of_a_real_system_and_help_documents_them(capsys):
    args = build_parser().parse_args(["dtrack", "--body", "0=WT"])
    assert (args.bind, args.port, args.provider, args.tracker_frame) == (
        "0.0.0.0",
        5000,
        "ART",
        "ART",
    )
    assert (args.rate, args.sigma_mm, args.sigma_deg, args.timestamps) == (
        60.0,
        0.5,
        0.1,
        "receive",
    )
    assert args.body == [(0, "WT")] and args.static == [] and args.marker == []
    assert args.tool == [] and args.flystick == []
    with pytest.raises(SystemExit):
        build_parser().parse_args(["dtrack", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    for documented in (
        "--body ID=FRAME",
        "--tool ID=FRAME",
        "--flystick ID=FRAME",
        "(default: 5000)",
        "(default: 0.5)",
        "(default: ART)",
        "ts2",
    ):
        assert documented in help_text
    assert "--scenario" not in help_text


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        ([], "no DTrack body mapped to a frame: give --body ID=FRAME"),
        (["--body", "0=WT", "--body", "0=HT"], "--body 0 is given twice (WT, HT)"),
        (["--tool", "0=P", "--tool", "0=Q"], "--tool 0 is given twice (P, Q)"),
        (["--flystick", "1=FS", "--body", "0=FS"], "two edges would be named 'ART_FS'"),
        (["--body", "0=HT", "--static", "WT"], "static body 'WT' is not a mapped body's frame"),
        (["--body", "0=HT", "--provider", "a/b"], "a/b"),
        (["--body", "0=HT", "--rate", "-1"], "rate must be a number >= 0"),
    ],
)
def test_mistakes_exit_2_with_the_reason(capsys, flags, message):
    args = build_parser().parse_args(["dtrack", *flags])
    assert args.func(args) == 2
    assert message in capsys.readouterr().err


def test_the_real_dtrack_path_and_io_load_no_simulator():
    code = (
        "import pkgutil, importlib, sys, ubitrack_agent.io, ubitrack_agent.commands.dtrack;"
        "[importlib.import_module(m.name) for m in"
        " pkgutil.walk_packages(ubitrack_agent.io.__path__, 'ubitrack_agent.io.')];"
        "print(sorted(m for m in sys.modules if m.startswith('ubitrack_agent.sim_trackers')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_demo_passes_its_scenario_mapping_to_dtrack():
    art = load_scenario().art
    args = build_parser().parse_args(["dtrack", *dtrack_flags(art, 5001)])
    assert dict(args.body) == art.bodies == {0: "WT", 1: "HT"}
    assert tuple(args.static) == art.static_bodies
    assert dict(args.marker) == art.markers
    assert (args.bind, args.port, args.provider, args.tracker_frame) == (
        "127.0.0.1",
        5001,
        art.provider,
        art.frame,
    )
    assert (args.sigma_mm, args.sigma_deg, args.rate) == (
        art.noise.position_mm,
        art.noise.rotation_deg,
        art.rate,
    )
    assert args.timestamps == "device"  # the simulator stamps ts with this host's clock

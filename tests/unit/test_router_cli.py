"""``ubitrack router``'s options: its settings resolve as every process's do, but its mode is
always router, on zenoh's port 7447 (loopback by default), with TLS and access control as
given; its status line counts what is linked to it. Pure: no session is opened."""

from __future__ import annotations

import argparse
import json
from types import SimpleNamespace

import pytest

from ubitrack_agent import cli
from ubitrack_agent.commands.router import router_settings, status_line
from ubitrack_agent.net import config


def parsed(*arguments: str) -> argparse.Namespace:
    return cli.build_parser("router").parse_args(["router", *arguments])


@pytest.fixture(autouse=True)
def no_settings_from_the_environment(monkeypatch):
    for name in (*config.SETTING_NAMES, "config"):
        monkeypatch.delenv(config.ENV_PREFIX + name.upper(), raising=False)


def test_the_default_is_a_router_on_loopback_on_zenohs_port():
    settings = router_settings(parsed())
    assert settings.mode == "router" and settings.connect == () and not settings.multicast
    assert settings.listen == (f"tcp/127.0.0.1:{config.DEFAULT_ROUTER_PORT}",)
    assert settings.zenoh_options()["mode"] == "router"


def test_listen_and_connect_flags_are_honoured():
    settings = router_settings(
        parsed("--listen", "tcp/0.0.0.0:7447", "--connect", "tcp/10.1.0.1:7447", "--quiet")
    )
    assert settings.listen == ("tcp/0.0.0.0:7447",)
    assert settings.connect == ("tcp/10.1.0.1:7447",)


def test_a_shared_file_or_the_environment_cannot_make_it_a_client(tmp_path, monkeypatch):
    """A machine's processes may share a settings file saying ``mode: client``; the router
    keeps its mode, and with it the listen endpoints (a client's would be dropped)."""
    shared = tmp_path / "site.yaml"
    shared.write_text("mode: client\nconnect: [tcp/10.1.0.1:7447]\nlisten: [tcp/0.0.0.0:7447]\n")
    assert router_settings(parsed("--config", str(shared))).mode == "router"
    monkeypatch.setenv("UBITRACK_MODE", "peer")
    assert router_settings(parsed("--listen", "tcp/0.0.0.0:7447")).mode == "router"


def test_an_explicit_other_mode_is_refused_with_exit_status_2(capsys):
    assert router_settings(parsed("--mode", "router")).mode == "router"
    assert cli.main(["router", "--mode", "client"]) == 2
    assert "a router's mode is always router" in capsys.readouterr().err


def test_a_router_listening_nowhere_is_refused(tmp_path, capsys):
    path = tmp_path / "router.yaml"
    path.write_text("listen: []\nconnect: [tcp/10.1.0.1:7447]\n")
    assert cli.main(["router", "--config", str(path)]) == 2
    assert "needs a listen endpoint" in capsys.readouterr().err


def test_bad_endpoints_are_refused_naming_the_flag(capsys):
    assert cli.main(["router", "--listen", "7447"]) == 2
    assert "command line: listen" in capsys.readouterr().err


def test_tls_and_access_control_reach_the_router_session(tmp_path):
    for name in ("ca.pem", "router.pem", "router-key.pem"):
        (tmp_path / name).write_text("PEM\n")
    (tmp_path / "acl.json").write_text('{"enabled": true, "default_permission": "deny"}\n')
    path = tmp_path / "router.yaml"
    path.write_text(
        "listen: [tls/0.0.0.0:7447]\ntls_root_ca: ca.pem\ntls_certificate: router.pem\n"
        "tls_key: router-key.pem\naccess_control: acl.json\n"
    )
    options = router_settings(parsed("--config", str(path))).zenoh_options()
    assert options["transport/link/tls"]["enable_mtls"] is True
    assert options["transport/link/tls"]["listen_certificate"] == str(tmp_path / "router.pem")
    assert options["access_control"]["default_permission"] == "deny"
    path.write_text(path.read_text().replace("tls/0.0.0.0", "tcp/0.0.0.0"))
    with pytest.raises(config.ConfigError, match="listen on tls/ endpoints only"):
        router_settings(parsed("--config", str(path)))


def test_the_config_command_shows_the_routers_settings(capsys):
    assert cli.main(["config", "--role", "router", "--mode", "client"]) == 2
    capsys.readouterr()
    assert cli.main(["config", "--role", "router"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["settings"]["mode"] == "router"
    assert printed["settings"]["listen"] == [f"tcp/127.0.0.1:{config.DEFAULT_ROUTER_PORT}"]


def test_the_status_line_counts_what_is_linked():
    linked = [SimpleNamespace(whatami=kind) for kind in ("router", "client", "client", "peer")]
    assert status_line(linked) == "router: 1 routers, 1 peers, 2 clients linked"
    assert status_line([]) == "router: 0 routers, 0 peers, 0 clients linked"

"""Settings resolution: defaults < file < environment < flags, with errors naming the source."""

import argparse
import json

import pytest

from ubitrack_agent import cli
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks


def test_embedded_defaults_are_loopback_peers_without_multicast():
    hub, member = config.resolve("hub", env={}), config.resolve("member", env={})
    for settings in (hub, member):
        assert settings.mode == "peer" and settings.multicast is False
        assert all("127.0.0.1" in e for e in settings.listen + settings.connect)
    assert hub.listen == (f"tcp/127.0.0.1:{config.DEFAULT_HUB_PORT}",) and hub.connect == ()
    assert member.connect == hub.listen
    assert member.key_prefix == "ubitrack/default"


def test_precedence_file_environment_flags(tmp_path):
    path = tmp_path / "ubitrack.yaml"
    path.write_text("mode: client\ndomain: lab\nconnect: [tcp/10.0.0.1:7447]\n")
    from_file = config.resolve("member", config_file=path, env={})
    assert (from_file.mode, from_file.domain) == ("client", "lab")
    assert from_file.connect == ("tcp/10.0.0.1:7447",)
    env = {"UBITRACK_DOMAIN": "hall", "UBITRACK_MULTICAST": "yes"}
    from_env = config.resolve("member", config_file=path, env=env)
    assert (from_env.mode, from_env.domain, from_env.multicast) == ("client", "hall", True)
    flags = {"domain": "room", "mode": None, "connect": ["tcp/127.0.0.1:9", "udp/1.2.3.4:5"]}
    final = config.resolve("member", config_file=path, env=env, flags=flags)
    assert (final.mode, final.domain) == ("client", "room")
    assert final.connect == ("tcp/127.0.0.1:9", "udp/1.2.3.4:5")


def test_config_file_from_environment_variable(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("prefix: tracking\n")
    settings = config.resolve("hub", env={"UBITRACK_CONFIG": str(path)})
    assert settings.key_prefix == "tracking/default"


def test_comma_separated_endpoints_in_environment():
    settings = config.resolve("member", env={"UBITRACK_CONNECT": "tcp/a:1, tcp/b:2"})
    assert settings.connect == ("tcp/a:1", "tcp/b:2")


def test_members_of_a_hub_that_also_connects_reach_the_hub_first():
    standby = config.Settings(listen=("tcp/0.0.0.0:7449",), connect=("tcp/10.0.0.1:7448",))
    member = config.member_of(standby)  # e.g. a standby agent's host manager
    assert member.connect == ("tcp/127.0.0.1:7449", "tcp/10.0.0.1:7448")
    member = config.member_of(config.member_of(standby))  # a host manager's worker
    assert member.connect == ("tcp/127.0.0.1:7449", "tcp/10.0.0.1:7448")
    client = config.member_of(config.Settings(mode="client", connect=("tcp/r:7447",)))
    assert (client.mode, client.connect, client.listen) == ("client", ("tcp/r:7447",), ())


@pytest.mark.parametrize(
    "content, fragment",
    [
        ("mode: mesh\n", "mode: must be one of"),
        ("colour: red\n", "unknown settings ['colour']"),
        ("connect: 7447\n", "connect: expected a list of endpoints"),
        ("listen: [localhost]\n", "is not a zenoh endpoint"),
        ("multicast: maybe\n", "multicast: expected true or false"),
        ("domain: a/b\n", "domain: 'a/b' must not contain '/'"),
        ("prefix: 'ubi/**'\n", "prefix:"),
        ("[1, 2]\n", "expected a mapping"),
        ("mode: [\n", "not valid YAML"),
    ],
)
def test_bad_files_are_reported_with_their_name(tmp_path, content, fragment):
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(config.ConfigError) as info:
        config.resolve("member", config_file=path, env={})
    assert str(info.value).startswith(str(path))
    assert fragment in str(info.value)


def test_bad_environment_and_flags_name_their_source(tmp_path):
    with pytest.raises(config.ConfigError, match=r"^environment: mode"):
        config.resolve("member", env={"UBITRACK_MODE": "bogus"})
    with pytest.raises(config.ConfigError, match=r"^command line: domain"):
        config.resolve("member", env={}, flags={"domain": "x y"})
    with pytest.raises(config.ConfigError, match="cannot read"):
        config.resolve("member", config_file=tmp_path / "missing.yaml", env={})


def test_zenoh_options_carry_the_settings():
    options = config.resolve("hub", env={}).zenoh_options()
    assert options["mode"] == "peer"
    assert options["scouting/multicast/enabled"] is False
    assert options["listen/endpoints"] == [f"tcp/127.0.0.1:{config.DEFAULT_HUB_PORT}"]


@pytest.mark.parametrize(
    "name", ["", "a//b", "/a", "a/", "*", "a/**", "x$*", "a#b", "a?x=1", "@/admin", "a b", "é"]
)
def test_hostile_key_names_are_rejected(name):
    with pytest.raises(ValueError):
        validate_key_chunks(name)
    with pytest.raises(ValueError):
        KeySpace("ubitrack/default").data(name)


def test_data_keys():
    assert KeySpace("ubitrack/lab").data("ART/HT") == "ubitrack/lab/data/ART/HT"


def test_config_command_prints_resolved_settings(capsys, monkeypatch):
    monkeypatch.setenv("UBITRACK_DOMAIN", "lab")
    assert cli.main(["config", "--role", "hub", "--listen", "tcp/127.0.0.1:9000"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["key_prefix"] == "ubitrack/lab"
    assert printed["settings"]["listen"] == ["tcp/127.0.0.1:9000"]


def test_config_command_reports_errors(capsys, monkeypatch):
    monkeypatch.setenv("UBITRACK_MODE", "bogus")
    assert cli.main(["config"]) == 2
    assert "environment: mode" in capsys.readouterr().err


def test_every_command_has_help(capsys):
    for name in cli.COMMAND_MODULES:
        with pytest.raises(SystemExit) as info:
            cli.main([name, "--help"])
        assert info.value.code == 0
        assert name in capsys.readouterr().out


def _security_files(directory):
    for name in ("ca.pem", "me.pem", "me-key.pem"):
        (directory / name).write_text("PEM\n")
    (directory / "acl.json").write_text('{"enabled": true, "default_permission": "deny"}\n')


def test_tls_and_access_control_files_are_relative_to_the_settings_file(tmp_path, monkeypatch):
    _security_files(tmp_path)
    path = tmp_path / "hub.yaml"
    path.write_text(
        "mode: router\nlisten: [tls/0.0.0.0:7448]\ntls_root_ca: ca.pem\n"
        "tls_certificate: me.pem\ntls_key: me-key.pem\naccess_control: acl.json\n"
    )
    monkeypatch.chdir("/")
    hub = config.resolve("hub", config_file=path, env={})
    assert hub.tls_root_ca == str(tmp_path / "ca.pem")
    options = hub.zenoh_options()
    assert options["transport/link/tls"]["enable_mtls"] is True
    assert options["transport/link/tls"]["connect_certificate"] == str(tmp_path / "me.pem")
    assert options["access_control"]["default_permission"] == "deny"


def test_members_of_an_access_controlled_hub_are_clients_with_its_tls(tmp_path):
    _security_files(tmp_path)
    path = tmp_path / "hub.yaml"
    path.write_text(
        "mode: router\nlisten: [tls/0.0.0.0:7448]\ntls_root_ca: ca.pem\n"
        "tls_certificate: me.pem\ntls_key: me-key.pem\naccess_control: acl.json\n"
    )
    member = config.member_of(config.resolve("hub", config_file=path, env={}))
    assert (member.mode, member.connect, member.listen) == ("client", ("tls/127.0.0.1:7448",), ())
    assert member.access_control is None and member.tls_key == str(tmp_path / "me-key.pem")
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    handed = config.from_arguments(parser.parse_args(config.as_flags(member)), role="member")
    assert handed == member  # what a child process resolves from the flags
    assert handed.zenoh_options()["connect/timeout_ms"] == -1  # waits for its router


@pytest.mark.parametrize(
    "content, fragment",
    [
        ("tls_root_ca: ca.pem\n", "go together"),
        ("tls_root_ca: missing.pem\n", "is not a readable file"),
        ("access_control: acl.json\n", "access_control needs TLS"),
        (
            "tls_root_ca: ca.pem\ntls_certificate: me.pem\ntls_key: me-key.pem\n"
            "access_control: acl.json\nlisten: [tcp/0.0.0.0:7448]\n",
            "listen on tls/ endpoints only",
        ),
        (
            "tls_root_ca: ca.pem\ntls_certificate: me.pem\ntls_key: me-key.pem\n"
            "access_control: ca.pem\nlisten: [tls/0.0.0.0:7448]\n",
            "expected a mapping",
        ),
    ],
)
def test_inconsistent_security_settings_are_refused(tmp_path, content, fragment):
    _security_files(tmp_path)
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(config.ConfigError, match=fragment):
        config.resolve("hub", config_file=path, env={})


def test_host_name_and_clock_offset_reach_child_processes():
    settings = config.resolve(
        "hub", env={"UBITRACK_HOST_NAME": "room", "UBITRACK_CLOCK_OFFSET_MS": "-250.5"}
    )
    assert (settings.host_name, settings.clock_offset_ms) == ("room", -250.5)
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    child = config.from_arguments(parser.parse_args(config.member_flags(settings)), "member")
    assert (child.host_name, child.clock_offset_ms) == ("room", -250.5)
    assert validate_key_chunks(config.resolve("member", env={}).host_name, single_chunk=True)


@pytest.mark.parametrize(
    ("name", "value", "fragment"),
    [
        ("UBITRACK_HOST_NAME", "a/b", "host_name"),
        ("UBITRACK_HOST_NAME", "*", "host_name"),
        ("UBITRACK_CLOCK_OFFSET_MS", "nan", "clock_offset_ms"),
        ("UBITRACK_CLOCK_OFFSET_MS", "1e300", "clock_offset_ms"),
        ("UBITRACK_CLOCK_OFFSET_MS", "soon", "clock_offset_ms"),
    ],
)
def test_bad_host_name_or_clock_offset_is_refused(name, value, fragment):
    with pytest.raises(config.ConfigError, match=fragment):
        config.resolve("member", env={name: value})


def test_a_client_of_a_host_manager_connects_to_it_first_then_where_it_connects():
    host = config.Settings(
        listen=("tcp/127.0.0.1:0",), connect=("tcp/127.0.0.1:7448",), domain="lab"
    )
    client = config.client_of(host, "tcp/127.0.0.1:40001")
    assert client.mode == "client" and client.listen == () and client.domain == "lab"
    assert client.connect == ("tcp/127.0.0.1:40001", "tcp/127.0.0.1:7448")
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    handed = config.from_arguments(parser.parse_args(config.as_flags(client)), role="member")
    assert handed.mode == "client" and handed.connect == client.connect and handed.listen == ()


def test_a_child_handed_its_network_as_flags_ignores_the_parents_environment(monkeypatch):
    """The parent was started with ``UBITRACK_LISTEN`` (its own port) and access control; its
    worker, a client listening nowhere, resolves from its flags alone in the environment it is
    given (``child_environment``): in the parent's, it listened on the parent's port."""
    parent_env = {
        "UBITRACK_LISTEN": "tcp/127.0.0.1:7447",
        "UBITRACK_ACCESS_CONTROL": "/etc/ubitrack/acl.yaml",
        "UBITRACK_CONFIG": "/etc/ubitrack/site.yaml",
        "UBITRACK_CHAOS_SEED": "3",
        "PATH": "/usr/bin",
    }
    host = config.Settings(listen=("tcp/127.0.0.1:0",), domain="lab")
    client = config.client_of(host, "tcp/127.0.0.1:40001")
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    flags = vars(parser.parse_args(config.as_flags(client)))
    given = config.child_environment(parent_env)
    assert given == {"UBITRACK_CHAOS_SEED": "3", "PATH": "/usr/bin"}  # not a setting: kept
    handed = config.resolve("member", env=given, flags=flags)
    assert handed.listen == () and handed.access_control is None
    assert handed == config.resolve("member", env={}, flags=flags)
    leaked = config.resolve("member", env={"UBITRACK_LISTEN": "tcp/127.0.0.1:7447"}, flags=flags)
    assert leaked.listen == ("tcp/127.0.0.1:7447",)  # what the parent's environment did

"""``net.session.zenoh_config``: the settings written over the zenoh file ``ZENOH_CONFIG``
names, if any."""

import json

from ubitrack_agent.net import config
from ubitrack_agent.net.session import CONFIG_VARIABLE, zenoh_config


def test_without_a_file_the_config_is_zenohs_default_with_the_settings():
    made = zenoh_config(config.resolve("hub", env={}), env={})
    assert json.loads(made.get_json("mode")) == "peer"
    assert json.loads(made.get_json("qos/publication")) == []
    assert json.loads(made.get_json("transport/link/tx/queue/batching/enabled")) is True
    drop = json.loads(made.get_json("transport/link/tx/queue/congestion_control/drop"))
    assert drop["wait_before_drop"] == config.DROP_WAIT_US == 10_000  # us, zenoh's is 1,000


def test_the_file_is_the_base_and_the_settings_win(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text(
        "{ mode: 'router',"
        " transport: { link: { tx: { queue: { batching: { enabled: false } } } } },"
        " qos: { publication: [ { key_exprs: ['**/data/**'], config: { express: true } } ] } }"
    )
    made = zenoh_config(config.resolve("member", env={}), env={CONFIG_VARIABLE: str(path)})
    assert json.loads(made.get_json("mode")) == "peer"  # the settings' own entry
    assert json.loads(made.get_json("transport/link/tx/queue/batching/enabled")) is False
    (rule,) = json.loads(made.get_json("qos/publication"))
    assert rule["key_exprs"] == ["**/data/**"] and rule["config"]["express"] is True


def test_a_child_process_inherits_the_file():
    env = {CONFIG_VARIABLE: "/etc/zenoh.json5", "UBITRACK_MODE": "client"}
    assert config.child_environment(env) == {CONFIG_VARIABLE: "/etc/zenoh.json5"}

"""``ubitrack status --dot``: labels escaped once, so Graphviz breaks the line where the label
says and shows no literal backslash-n (issue [surface])."""

from __future__ import annotations

from ubitrack_agent.commands.status import live_dot
from ubitrack_agent.graph.dot import quote


def test_quote_escapes_once_and_keeps_line_breaks_as_dot_newlines():
    assert quote('a "b"\nc\\d') == '"a \\"b\\"\\nc\\\\d"'


def test_live_dot_breaks_component_labels_into_two_lines():
    status = {
        "key_prefix": "ubitrack/demo",
        "srg": [{"from": "ART", "to": "HT", "type": "6D", "static": False}],
        "components": {
            "fusion-1a": {"service": "fusion", "alive": True, "derives": [["C", "WT", "6D"]]}
        },
    }
    dot = live_dot(status)
    assert '[label="fusion 6D\\nfusion-1a", style=dashed' in dot
    assert "\\\\n" not in dot
    assert '"ART" -> "HT" [label="6D"];' in dot

"""Frame names a query may have meant (``ubitrack_agent/graph/frame_names.py``, issue 31):
"did you mean" for frames named almost like announced ones."""

from __future__ import annotations

from ubitrack_agent.graph.frame_names import close_frames, frame_hint

ANNOUNCED = {"C", "A", "HT", "WT", "IP", "F1", "F2", "ART", "Marker1", "Marker2"}


def test_close_frames_differ_in_case_or_by_a_small_edit():
    assert close_frames("c", ANNOUNCED) == ["C"]
    assert close_frames("ht", ANNOUNCED) == ["HT"]
    assert close_frames("HTT", ANNOUNCED) == ["HT"]
    assert close_frames("marker3", ANNOUNCED) == ["Marker1", "Marker2"]
    assert close_frames("F3", ANNOUNCED) == []  # one of two characters: too far
    assert close_frames("ARTT", ANNOUNCED) == ["ART"]
    assert close_frames("NOPE", ANNOUNCED) == []
    assert close_frames("C", ANNOUNCED) == []  # announced itself: nothing to suggest
    assert close_frames("x", ["X", "x2"]) == ["X", "x2"]  # the same but for case comes first


def test_a_hint_names_the_relation_meant():
    assert frame_hint("c", "a", ANNOUNCED) == "did you mean C->A?"
    assert frame_hint("C", "ht", ANNOUNCED) == "did you mean C->HT?"
    assert (
        frame_hint("C", "marker3", ANNOUNCED) == "did you mean C->Marker1 (or Marker2 for marker3)?"
    )
    assert frame_hint("C", "NOPE", ANNOUNCED) is None
    assert frame_hint("C", "A", ANNOUNCED) is None  # both announced: the reason is another
    assert frame_hint("c", "a", set()) is None  # no agent's SRG to go by

"""A small building as providers announce it, for the replanning tests: rooms ``R<r>``
surveyed into ``B``, each seen by a tracker ``t<r>`` and a worse one ``u<r>``."""

from __future__ import annotations

from ubitrack_agent.agent.announcements import provider_entries


def edge(name, source, target, edge_type="6D", **extra):
    return {"name": name, "from": source, "to": target, "type": edge_type, **extra}


def tracker(name, room, sigma=1e-3):
    """A tracker ``name`` in ``room`` seeing the room's two bodies ``H<room>_1``, ``_2``."""
    frame = name.upper()
    return provider_entries(
        name,
        [
            edge("room", f"R{room}", frame, static=True),
            *(edge(f"H{j}", frame, f"H{room}_{j}", rate=60, sigma=sigma) for j in (1, 2)),
        ],
    )


def building(rooms=3):
    """Rooms ``R<r>`` surveyed into ``B``, each with tracker ``t<r>`` and a worse ``u<r>``."""
    fragments = {
        "survey": provider_entries(
            "survey", [edge(f"R{r}", "B", f"R{r}", static=True) for r in range(rooms)]
        )
    }
    for r in range(rooms):
        fragments[f"t{r}"] = tracker(f"t{r}", r)
        fragments[f"u{r}"] = tracker(f"u{r}", r, sigma=5e-3)
    return fragments

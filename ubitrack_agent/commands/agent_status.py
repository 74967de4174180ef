"""What the agent says about a relation, for the commands that ask for one (``subscribe``,
``calibrate``): the reason it cannot serve it, read from its status (``ubitrack status``)."""

from __future__ import annotations

import json
from typing import Any


def unsolved_reason(session: Any, keys: Any, relation: Any) -> str:
    """Why the agent does not serve ``relation`` (a ``RelationId``), from its status, as a
    clause to append to a message; empty when it serves it or gives no reason."""
    from ubitrack_agent.agent.flows import plan_name
    from ubitrack_agent.net.transport import fetch_latest

    replies = fetch_latest(session, keys.agent_status(), timeout=1.0)
    if not replies:
        return f"; no agent answers on {keys.agent_status()}"
    try:
        reason = json.loads(replies[0]).get("unsolved", {}).get(plan_name(relation))
    except (ValueError, AttributeError):  # not the agent's JSON status, or an unknown type
        return ""
    return f": the agent cannot serve it: {reason}" if reason else ""

"""How the project runs its own modules in a child process: ``python -P -m <module>``.

``-P`` (Python 3.11) keeps the working directory off the child's ``sys.path``, so a folder of the
user's (a ``services/`` or ``ubitrack_agent/`` beside where ``ubitrack agent`` was started)
cannot replace the module the child runs; the modules themselves live under ``ubitrack_agent``
(see ``setup.py``), so no other distribution's top-level package can either (issue [newcomer]).
"""

from __future__ import annotations

import sys


def module_command(module: str, *arguments: str, python: str = sys.executable) -> list[str]:
    """The command line that runs ``module`` (e.g. ``ubitrack_agent.services.host``) with
    ``arguments`` in ``python``, isolated from the working directory."""
    return [python, "-P", "-m", module, *arguments]

"""One line of a command's output stream (its JSON lines, its status line), written whole.

``print(text, flush=True)`` writes the text and its newline in two calls; when standard output
and standard error share a file (``command > log 2>&1``, a test's log, a service manager's
journal), a warning a zenoh callback thread logs in between lands on the same line, and a
reader of JSON lines gets ``{...}<warning>``: measured, 3,000 of 20,000 lines of 1.1 KB mixed
with a thread logging beside them, none written so (``tests/integration/test_output_lines.py``).
"""

from __future__ import annotations

import sys
from typing import TextIO


def write_line(text: str, stream: TextIO | None = None) -> None:
    """Write ``text`` and its newline to ``stream`` (standard output by default) in one call,
    and flush it."""
    out = sys.stdout if stream is None else stream
    out.write(text + "\n")
    out.flush()

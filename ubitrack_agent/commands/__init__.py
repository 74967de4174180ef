"""Subcommands of the ``ubitrack`` command line, one module each (see :mod:`ubitrack_agent.cli`),
and :mod:`.signals`, the shutdown they share."""

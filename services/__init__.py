"""Pattern services: the algorithms behind the pattern templates (and, later, their workers)."""

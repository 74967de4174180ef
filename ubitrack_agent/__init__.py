"""Ubitrack Agent: spatial relationship patterns for tracking and calibration over zenoh.

The package is split in three layers (see ``docs/architecture.md``):

* :mod:`ubitrack_agent.core`: measurement types, the wire codec and SE(3) maths.
  It depends on numpy, scipy and msgpack only.
* the graph side (SRG, templates, planner), pure and usable offline;
* the runtime side (configuration, zenoh sessions, agent, client APIs).
"""

__version__ = "0.1.0"

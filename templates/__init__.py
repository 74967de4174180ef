"""The template service descriptions (``*.yaml``), one file per spatial relationship pattern
(paper sections 3.2 and 5.2.1). A package only so that the files ship in the wheel and are
found with :mod:`importlib.resources` (``ubitrack_agent.graph.templates.shipped_templates``);
it holds no code."""

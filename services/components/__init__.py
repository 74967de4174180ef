"""Registered pattern services, one module per family; importing a module registers its services.

Port names are the edge names of the pattern's template in ``templates/`` (``AB``, ``BC``...), so
a planned component's input bindings map onto ports directly.
"""

from services.components import auxiliary, basic, estimation, fusion  # noqa: F401

"""Registered pattern services, one module per family; importing a module registers its services.

:func:`ubitrack_agent.services.registry.load_components` imports every module of this package, so a
new service is a class decorated with ``@register`` in any module here. Port names are the edge
names of the pattern's template in ``templates/`` (``AB``, ``BC``...), so a planned component's
input bindings map onto ports directly; ``tests/unit/test_contract.py`` checks that the two
agree.
"""

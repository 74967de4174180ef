"""The order in which a container starts a batch of components: relations flowing first.

A container starts the components it is given one after the other (a few milliseconds each,
more under load: ``services.container``), and a relation flows once its producer (the component
putting on the relation's key that an application reads) and every component of the batch it
reads from, directly or not, run. Started in the agent's order, the producers came last (issue
28: a restored container added its components one at a time, the one that puts on the relation
key last), so every application waited for the whole batch. Here each producer comes right
after the components it reads from in the batch (those first, upstream before downstream), the
producers needing the fewest of them first; the components no relation needs follow in their
order. So the first application flows after its own derivation is up, not after the batch.
Ties keep the given order; a wiring cycle (none is planned) is broken where it is met.

Pure. O(producers x (components + bindings)) to weigh the producers, O(components + bindings)
to order them.
"""

from __future__ import annotations

from collections.abc import Sequence

from ubitrack_agent.net.spec import ComponentSpec


def start_order(specs: Sequence[ComponentSpec]) -> tuple[ComponentSpec, ...]:
    """``specs`` in the order that gets their relations flowing soonest (module docstring)."""
    producer_of = {key: index for index, spec in enumerate(specs) for key in spec.outputs.values()}
    reads = [
        [producer_of[b.key] for b in spec.inputs if producer_of.get(b.key, index) != index]
        for index, spec in enumerate(specs)
    ]

    def upstream(index: int, placed: set[int]) -> list[int]:
        """The components ``index`` reads from, transitively, not in ``placed``, each after
        those it reads from, then ``index`` (depth first, iterative: no recursion limit)."""
        order: list[int] = []
        stack = [(index, iter(reads[index]))]
        seen = {index}
        while stack:
            node, pending = stack[-1]
            following = next((i for i in pending if i not in seen and i not in placed), None)
            if following is None:
                stack.pop()
                order.append(node)
            else:
                seen.add(following)
                stack.append((following, iter(reads[following])))
        return order

    producers = [index for index, spec in enumerate(specs) if spec.relations]
    weight = {index: len(upstream(index, set())) for index in producers}
    placed: set[int] = set()
    order: list[int] = []
    for index in sorted(producers, key=lambda index: (weight[index], index)):
        if index in placed:  # another producer reads from it: started already
            continue
        for member in upstream(index, placed):
            placed.add(member)
            order.append(member)
    order += [index for index in range(len(specs)) if index not in placed]
    return tuple(specs[index] for index in order)

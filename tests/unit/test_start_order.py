"""The order a container starts a batch in (``services/start_order.py``): each relation's
producer right after what it reads in the batch, the smallest derivation first."""

from ubitrack_agent.net.spec import ComponentSpec, InputBinding
from ubitrack_agent.services.start_order import start_order


def spec(instance, *reads, relation=False):
    """A component reading the outputs of ``reads`` (instances of the batch, or provider keys
    ``d/<provider>``), putting on a relation key if ``relation``."""
    return ComponentSpec(
        instance=instance,
        service="x",
        inputs=tuple(
            InputBinding(f"p{i}", f"d/{name}/out" if name[0].islower() else f"d/{name}")
            for i, name in enumerate(reads)
        ),
        outputs={"out": f"d/{instance}/out"},
        relations={"out": (f"rel/{instance}",)} if relation else {},
    )


def names(specs):
    return [s.instance for s in specs]


def test_each_producer_follows_its_own_derivation_the_smallest_first():
    # Two applications: "fused" reads two chains of two, "single" one chain; given in the
    # agent's order (producers last), "single" needs 2 components, "fused" 5.
    batch = [
        spec("inv_a", "ART"),
        spec("inv_b", "IR"),
        spec("cat_a", "inv_a", "ART"),
        spec("cat_b", "inv_b", "IR"),
        spec("inv_c", "ART"),
        spec("fused", "cat_a", "cat_b", relation=True),
        spec("single", "inv_c", relation=True),
    ]
    assert names(start_order(batch)) == [
        "inv_c",
        "single",
        "inv_a",
        "cat_a",
        "inv_b",
        "cat_b",
        "fused",
    ]


def test_a_producer_another_reads_starts_once_and_the_rest_keep_their_order():
    batch = [
        spec("spare", "ART"),
        spec("outer", "inner", relation=True),
        spec("inner", "ART", relation=True),
        spec("other", "IR"),
    ]
    ordered = start_order(batch)
    assert names(ordered) == ["inner", "outer", "spare", "other"]
    assert sorted(names(ordered)) == sorted(names(batch))  # each once, none lost


def test_a_batch_without_producers_or_with_a_cycle_is_whole():
    plain = [spec("a", "ART"), spec("b", "a")]
    assert names(start_order(plain)) == ["a", "b"]
    cycle = [spec("a", "b"), spec("b", "a", relation=True)]
    assert names(start_order(cycle)) == ["a", "b"]
    assert start_order([]) == ()

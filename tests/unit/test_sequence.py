"""The numbers a publisher's puts carry and the gaps a reader counts (``net.sequence``)."""

from __future__ import annotations

from ubitrack_agent.net.sequence import MAX_SOURCES, Gaps, Numbering


def test_numbers_in_order_count_no_gap_and_skipped_ones_count_each():
    numbering, gaps = Numbering(), Gaps()
    reader = gaps.reader()
    puts = [numbering.next() for _ in range(10)]
    assert [reader.seen(put) for put in puts[:4]] == [0, 0, 0, 0]
    assert reader.seen(puts[7]) == 3  # 4, 5 and 6 were dropped on the way
    assert reader.seen(puts[9]) == 1
    assert gaps.missed == 4


def test_a_late_reader_counts_no_gap_before_its_first_sample_nor_for_an_old_one():
    numbering, gaps = Numbering(), Gaps()
    reader = gaps.reader()
    puts = [numbering.next() for _ in range(6)]
    assert reader.seen(puts[3]) == 0  # started after three puts: not lost to it
    assert reader.seen(puts[2]) == 0  # not after the last: nothing to count
    assert reader.seen(puts[4]) == 0
    assert gaps.missed == 0


def test_two_publishers_on_one_key_are_counted_apart():
    first, second, gaps = Numbering(), Numbering(), Gaps()
    reader = gaps.reader()
    a = [first.next() for _ in range(3)]
    b = [second.next() for _ in range(3)]
    seen = [reader.seen(x) for x in (a[0], b[0], a[1], b[1], a[2], b[2])]  # interleaved
    assert seen == [0] * 6 and gaps.missed == 0
    assert reader.seen(first.next()) == 0 and reader.seen(second.next()) == 0


def test_samples_without_a_number_count_nothing():
    gaps = Gaps()
    reader = gaps.reader()
    assert reader.seen(None) == 0 and reader.seen(b"foreign") == 0
    assert gaps.missed == 0


def test_readers_of_one_holder_add_up_and_a_forgotten_publisher_starts_again():
    gaps = Gaps()
    one, two = gaps.reader(), gaps.reader()
    numbering = Numbering()
    puts = [numbering.next() for _ in range(5)]
    one.seen(puts[0]), one.seen(puts[2])
    two.seen(puts[0]), two.seen(puts[4])
    assert gaps.missed == 1 + 3
    others = [Numbering() for _ in range(MAX_SOURCES)]
    for other in others:  # the first publisher is now the one heard from least recently
        one.seen(other.next())
    assert one.seen(numbering.next()) == 0  # forgotten: a first sample again, not a gap
    assert gaps.missed == 4

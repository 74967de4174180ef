"""The numbers a publisher's puts carry and the gaps a reader counts (``net.sequence``)."""

from __future__ import annotations

from ubitrack_agent.net.address import tag
from ubitrack_agent.net.sequence import MAX_SOURCES, Gaps, Numbering

KEY = "ubitrack/domain/relation/C/A/6D/dynamic"


def test_numbers_in_order_count_no_gap_and_skipped_ones_count_each():
    numbering, gaps = Numbering(KEY), Gaps()
    reader = gaps.reader(KEY)
    puts = [numbering.next() for _ in range(10)]
    assert [reader.take(put) for put in puts[:4]] == [0, 0, 0, 0]
    assert reader.take(puts[7]) == 3  # 4, 5 and 6 were dropped on the way
    assert reader.take(puts[9]) == 1
    assert gaps.missed == 4


def test_a_late_reader_counts_no_gap_before_its_first_sample_nor_for_an_old_one():
    numbering, gaps = Numbering(KEY), Gaps()
    reader = gaps.reader(KEY)
    puts = [numbering.next() for _ in range(6)]
    assert reader.take(puts[3]) == 0  # started after three puts: not lost to it
    assert reader.take(puts[2]) == 0  # not after the last: nothing to count
    assert reader.take(puts[4]) == 0
    assert gaps.missed == 0


def test_two_publishers_on_one_key_are_counted_apart():
    first, second, gaps = Numbering(KEY), Numbering(KEY), Gaps()
    reader = gaps.reader(KEY)
    a = [first.next() for _ in range(3)]
    b = [second.next() for _ in range(3)]
    seen = [reader.take(x) for x in (a[0], b[0], a[1], b[1], a[2], b[2])]  # interleaved
    assert seen == [0] * 6 and gaps.missed == 0
    assert reader.take(first.next()) == 0 and reader.take(second.next()) == 0


def test_samples_without_a_number_count_nothing():
    gaps = Gaps()
    reader = gaps.reader(KEY)
    assert reader.take(None) == 0 and reader.take(b"foreign") == 0
    assert gaps.missed == 0


def test_readers_of_one_holder_add_up_and_a_forgotten_publisher_starts_again():
    gaps = Gaps()
    one, two = gaps.reader(KEY), gaps.reader(KEY)
    numbering = Numbering(KEY)
    puts = [numbering.next() for _ in range(5)]
    one.take(puts[0]), one.take(puts[2])
    two.take(puts[0]), two.take(puts[4])
    assert gaps.missed == 1 + 3
    others = [Numbering(KEY) for _ in range(MAX_SOURCES)]
    for other in others:  # the first publisher is now the one heard from least recently
        one.take(other.next())
    assert one.take(numbering.next()) == 0  # forgotten: a first sample again, not a gap
    assert gaps.missed == 4


def test_a_sample_put_on_another_key_is_refused_and_counted_not_numbered():
    """A sample zenoh delivered on another key than its publisher's (``net.address``) is
    refused, whatever its number, and counted apart from the gaps."""
    gaps = Gaps()
    reader = gaps.reader(KEY)
    here, elsewhere = Numbering(KEY), Numbering(KEY.replace("C/A", "C/HT"))
    assert reader.take(here.next()) == 0
    assert reader.take(elsewhere.next()) is None
    assert reader.take(tag("ubitrack/domain/control/fusion-1")) is None  # a command's
    assert reader.take(here.next()) == 0  # the next of its own publisher: no gap
    assert (gaps.missed, gaps.misaddressed) == (0, 2)


def test_a_wildcard_reader_checks_each_sample_against_its_own_key():
    gaps = Gaps()
    reader = gaps.reader(None)
    numbering, other = Numbering(KEY), Numbering(KEY + "x")
    assert reader.take(numbering.next(), KEY) == 0
    assert reader.take(other.next(), KEY) is None  # put on KEY + "x", delivered as KEY
    assert reader.take(other.next(), KEY + "x") == 0
    assert reader.take(numbering.next()) == 0  # no key to check against: taken
    assert (gaps.missed, gaps.misaddressed) == (0, 1)

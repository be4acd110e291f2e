"""``datagram_bounds``: frames of given sizes cut greedily into datagrams of
at most ``limit`` bytes, a frame never split, one larger than the limit
alone. Exact integer results: no tolerance."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mavwire import MAX_DATAGRAM_BYTES, datagram_bounds


def test_no_frames_no_datagrams() -> None:
    assert datagram_bounds([]) == []
    assert datagram_bounds(()) == []


def test_frames_that_fill_the_limit_exactly_share_one_datagram() -> None:
    assert datagram_bounds([600, 600], 1200) == [(2, 1200)]
    assert datagram_bounds([600, 601], 1200) == [(1, 600), (2, 1201)]


def test_a_frame_bigger_than_the_limit_goes_alone() -> None:
    assert datagram_bounds([100, 1300, 100], 1200) == [(1, 100), (2, 1400), (3, 1500)]
    assert datagram_bounds([1300], 1200) == [(1, 1300)]
    assert datagram_bounds([1300, 10, 10], 1200) == [(1, 1300), (3, 1320)]


def test_the_shared_limit_and_the_counts_it_gives() -> None:
    """1200 bytes (see ``MAX_DATAGRAM_BYTES``): 18 setpoints of 65 bytes, 30
    LOCAL_POSITION_NED of 40 bytes per datagram."""
    assert MAX_DATAGRAM_BYTES == 1200
    assert datagram_bounds([65] * 40) == [(18, 1170), (36, 2340), (40, 2600)]
    assert datagram_bounds([40] * 61) == [(30, 1200), (60, 2400), (61, 2440)]


@given(
    st.lists(st.one_of(st.integers(1, 300), st.just(2000)), max_size=80),
    st.integers(1, 1500),
)
def test_bounds_cover_every_frame_in_order_and_are_greedy(sizes: list[int], limit: int) -> None:
    cuts = datagram_bounds(sizes, limit)
    first = start = 0
    for j, (stop, end) in enumerate(cuts):
        assert stop > first and end == start + sum(sizes[first:stop])  # contiguous, nonempty
        assert end - start <= limit or stop - first == 1  # fits, or one oversized frame
        if j + 1 < len(cuts):  # greedy: the next frame would not have fitted
            assert end - start + sizes[stop] > limit
        first, start = stop, end
    assert (first, start) == (len(sizes), sum(sizes))

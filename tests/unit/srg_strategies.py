"""Hypothesis strategies for random SRGs: small multigraphs with parallel and opposite edges of
mixed types, static and dynamic, and a query between two of their frames."""

from __future__ import annotations

from hypothesis import strategies as st

edges = st.lists(
    st.tuples(
        st.integers(0, 4),
        st.integers(0, 4),
        st.sampled_from(["6D", "6D", "3D", "2D", "3x4"]),
        st.booleans(),
    ).filter(lambda e: e[0] != e[1]),
    min_size=1,
    max_size=9,
)
"""Edges ``(a, b, type, static)`` between frames ``N0``..``N4``."""

queries = st.tuples(st.integers(0, 4), st.integers(0, 4), st.booleans()).filter(
    lambda q: q[0] != q[1]
)
"""Queries ``(a, b, static)`` of a 6D relation ``N<a> -> N<b>``."""

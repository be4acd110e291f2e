"""``supervisor.ids_key``: a step's ids as one tuple of ints, handed on
without copies (a step per network reads all N ids several times a period)."""

from __future__ import annotations

import numpy as np

from gcs_swarm.control.supervisor import ids_key


def test_a_tuple_of_ints_is_its_own_key_and_anything_else_becomes_ints() -> None:
    ids = (3, 5, 9)
    assert ids_key(ids) is ids
    assert ids_key(ids, known=ids) is ids
    same = tuple([3, 5, 9])  # equal, another object: itself, no copy
    assert ids_key(same, known=ids) is same
    for other in ([3, 5, 9], np.array([3, 5, 9]), (3, np.int64(5), 9), (True, 5, 9)):
        key = ids_key(other, known=ids)  # type: ignore[arg-type]
        assert key == (1 if other[0] is True else 3, 5, 9)
        assert all(type(x) is int for x in key)
        assert key is not other

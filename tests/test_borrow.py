"""Borrowed views (``wmr._borrow``): the same memory without reference counts.

Oracles: the original arrays (a write through a borrowed view is seen by the owner; a read gives
the owner's values, strides included), a namedtuple's own class and field values, and the
identity in plain Python; the same loop with and without borrowing.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np
from numpy.testing import assert_array_equal

from wmr._borrow import borrowed

Pair = namedtuple("Pair", ("a", "b", "n"))


@numba.njit
def _write_through(x, y):
    bx, by = borrowed((x, y))
    for i in range(bx.shape[0]):
        bx[i] = 2.0 * by[i, 1]  # y is a strided view: its strides must survive
    return bx.shape[0], by.strides[0]


@numba.njit
def _fields(p):
    b = borrowed(p)
    b.a[0] = b.n + b.b.sum()
    return b.n, b.b.shape[0]


def test_a_borrowed_view_is_the_owners_memory():
    x = np.zeros(5)
    base = np.arange(30.0).reshape(5, 6)
    y = base[:, ::2]  # non-contiguous
    n, stride = _write_through(x, y)
    assert (n, stride) == (5, y.strides[0])
    assert_array_equal(x, 2.0 * y[:, 1])


def test_a_namedtuple_is_borrowed_field_by_field():
    p = Pair(np.zeros(2), np.array([1.0, 2.0, 3.0]), 4)
    assert _fields(p) == (4, 3)
    assert p.a[0] == 10.0


def test_borrowed_is_the_identity_in_python():
    p = Pair(np.zeros(2), np.ones(3), 1)
    assert borrowed(p) is p


def _loop(borrow):
    @numba.njit
    def loop(p, s, n):
        if borrow:
            p, s = borrowed((p, s))
        t = 0.0
        for k in range(n):
            v = p.b[k % 3]  # a field read from the namedtuple, a view made per step
            w = s[1:3]
            if v > 1.5:
                t += w[0] * v
            else:
                t -= w[1]
            s[0] = t
        return t

    return loop


def test_a_loop_over_borrowed_arrays_gives_the_same_numbers():
    """Views of borrowed arrays, fields of a borrowed namedtuple, writes, in a loop with branches
    (what the counts were about); what borrowing saves is measured by ``wmr bench``."""
    p = Pair(np.zeros(2), np.array([1.0, 2.0, 3.0]), 4)
    s1, s2 = np.arange(4.0), np.arange(4.0)
    assert _loop(False)(p, s1, 1000) == _loop(True)(p, s2, 1000)
    assert_array_equal(s1, s2)

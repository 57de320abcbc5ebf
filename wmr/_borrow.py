"""Borrowed views: the loop's arrays without their reference counts (issue 25).

Inside a jitted function numba counts the references of every array variable: binding an array
to a new name (an inlined law's parameters, a field read from a namedtuple of parameters) or
making a view increments its owner's count, and the variable's death decrements it -- an atomic
read-modify-write each (``NRT_incref`` / ``NRT_decref``).  numba's pruning pass removes the
pairs only where the code between them is simple; around a law with branches it cannot, and
the counts cost more than the law (perf, fixed PID on the lemniscate: 37 % of the step was the
two functions).

:func:`borrowed` returns ``x`` with every array in it (an array, or one inside a tuple or a
namedtuple, recursively) replaced by a view with no owner (a null ``meminfo``): the same data,
shape and strides, whose counts are no-ops.  The loop (``wmr.closedloop.step``) borrows its
arguments once per call; the caller holds the owners for the whole call, so the views cannot
outlive their data, and nothing borrowed leaves the call.  In plain Python (the Python driver,
``NUMBA_DISABLE_JIT``) :func:`borrowed` is the identity.  The numbers are the same: only the
bookkeeping changes.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["borrowed"]


def borrowed(x):
    """``x`` with its arrays replaced by views without an owner (jitted code); ``x`` itself in
    plain Python."""
    return x


@intrinsic
def _borrowed_array(typingctx, arr):
    """A view of ``arr`` (same data, shape, strides) with a null ``meminfo`` and ``parent``."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        cls = context.make_array(sig.args[0])
        src = cls(context, builder, args[0])
        out = cls(context, builder)
        context.populate_array(out, data=src.data, shape=src.shape, strides=src.strides,
                               itemsize=src.itemsize, meminfo=None)  # fmt: skip
        out.parent = cgutils.get_null_value(out.parent.type)
        return out._getvalue()

    return arr(arr), codegen


def _tuple_impl(x):
    """The implementation of :func:`borrowed` for a (named) tuple: borrow each item, rebuild."""
    n = len(x)
    items = ", ".join(f"borrowed(x[{i}])" for i in range(n))
    if isinstance(x, types.BaseNamedTuple):
        glb = {"borrowed": borrowed, "cls": x.instance_class}
        src = f"def impl(x):\n    return cls({items})\n"
    else:
        glb = {"borrowed": borrowed}
        src = f"def impl(x):\n    return ({items}{',' if n == 1 else ''})\n"
    exec(src, glb)  # noqa: S102 - a fixed template, one item per field
    return glb["impl"]


@overload(borrowed, inline="always")
def _borrowed(x):
    if isinstance(x, types.Array):
        return lambda x: _borrowed_array(x)
    if isinstance(x, types.BaseTuple) and len(x) > 0:  # namedtuples included
        return _tuple_impl(x)
    return lambda x: x

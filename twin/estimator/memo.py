"""The latest results of a pure computation on arrays, given again for the same inputs to the bit.

A diagnosis asks many times for the same chain evaluation or the same regressor: a refit starts where the previous
fit ended, models that differ only in their effect terms evaluate the geometry at the same point, and every feature
family builds the gravity-torque regressor of the same rows. :class:`KeptResults` keeps the latest few results of one
function, by the bytes of its array inputs (their dtype and shape with them) and the identity of its other inputs
(kept referenced by the entry, so that an identity is not reused while its key lives), or of an ``owner`` held weakly
(an entry whose owner is gone is dropped, and is never given to another object). The results it gives are the
arrays the function computed (read-only: a caller that wrote into one would change what the next caller gets), so
they are the same numbers to the bit. Bounded: at most ``entries`` results and ``max_bytes`` bytes of them (but the
latest).
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from typing import Any, Callable

import numpy as np

__all__ = ["KeptResults", "array_key"]


def array_key(a: Any) -> tuple:
    """The key of an array input: its dtype, shape and bytes (an array-like is read as an array first)."""
    a = np.asarray(a)
    return (a.dtype.str, a.shape, a.tobytes())


def _nbytes(value: Any) -> int:
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 0


def _read_only(value: Any) -> None:
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, (tuple, list)):
        for v in value:
            _read_only(v)


class KeptResults:
    """The latest ``entries`` results of a computation (at most ``max_bytes`` bytes of arrays but the latest), by
    key. :meth:`get_or_compute` gives the kept result of an equal key, else computes it, marks its arrays read-only
    and keeps it. ``pins``: the objects whose identity is part of the key, held while the entry lives."""

    def __init__(self, entries: int, max_bytes: int):
        if not isinstance(entries, int) or entries < 1:
            raise ValueError(f"entries must be a positive integer, got {entries!r}")
        if not isinstance(max_bytes, int) or max_bytes < 0:
            raise ValueError(f"max_bytes must be a non-negative integer, got {max_bytes!r}")
        self.entries = entries
        self.max_bytes = max_bytes
        self._kept: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._kept)

    def clear(self) -> None:
        """Forget every kept result."""
        with self._lock:
            self._kept.clear()

    def get(self, key: tuple, owner: Any = None) -> Any | None:
        """The kept result of ``key`` (kept for ``owner``, when one was given to :meth:`put`), or None."""
        with self._lock:
            got = self._kept.get(key)
            if got is None or (got[3] is not None and got[3]() is not owner):
                return None
            self._kept.move_to_end(key)
            return got[0]

    def put(self, key: tuple, value: Any, pins: tuple = (), *, owner: Any = None, nbytes: int | None = None) -> Any:
        """Keep ``value`` (its arrays made read-only) for ``key``; returns it. ``owner``: held weakly, the entry given
        only to it and dropped once it is gone; ``nbytes``: the value's size when it is not arrays, tuples or lists of
        them (the caller then makes its arrays read-only)."""
        _read_only(value)
        size = _nbytes(value) if nbytes is None else nbytes
        ref = None if owner is None else weakref.ref(owner)
        with self._lock:
            for k in [k for k, v in self._kept.items() if v[3] is not None and v[3]() is None]:
                del self._kept[k]  # its owner is gone: nothing can ask for it again
            self._kept[key] = (value, pins, size, ref)
            self._kept.move_to_end(key)
            while len(self._kept) > 1 and (len(self._kept) > self.entries
                                           or sum(v[2] for v in self._kept.values()) > self.max_bytes):
                self._kept.popitem(last=False)
        return value

    def owners(self) -> list:
        """The weak references to the kept entries' owners (None for an entry without one), oldest first."""
        with self._lock:
            return [v[3] for v in self._kept.values()]

    def get_or_compute(self, key: tuple, compute: Callable[[], Any], pins: tuple = ()) -> Any:
        """The kept result of ``key``, else ``compute()`` kept."""
        got = self.get(key)
        if got is not None:
            return got
        return self.put(key, compute(), pins)

"""Host data derived from a body (layouts, constraint set-ups, compiled closures), kept in
small bounded caches keyed by what it depends on.

A key is the body's structure (its pytree structure: every static field, the name and
source left out, as no derived data reads them) and a digest of each array the data reads.
So two bodies of one structure but other lengths share nothing the lengths decide, and a
body's `id`, which a new body may take once it is collected, is never a key. Each cache
names the arrays it reads (`BodyCache(reads=...)`). A body's digests are remembered while
it lives: reading its arrays back to the host costs about a warm solve's time.
"""

import hashlib
import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from typing import TypeVar

import jax
import numpy as np

from ._body import Body, without_names

T = TypeVar("T")
RANGES = ("swing_lo", "swing_hi", "twist_lo", "twist_hi")  # what can move (the layouts)


def body_key(body: Body, reads: Sequence[str] = ()) -> tuple:
    """The key of host data derived from a (concrete) body that reads the arrays named
    `reads` ("lengths", "swing_lo", ...): its structure, then a digest per array."""
    ref, known = _SEEN.get(id(body), (None, None))
    if ref is None or ref() is not body:
        known = {"": jax.tree.structure(without_names(body))}
        _SEEN[id(body)] = (weakref.ref(body, _forget(id(body))), known)
    for name in reads:
        if name not in known:
            a = np.asarray(getattr(body, name))
            known[name] = hashlib.sha256(f"{a.dtype}{a.shape}".encode() + a.tobytes()).digest()
    return tuple(known[name] for name in ("", *reads))


_SEEN: dict[int, tuple[weakref.ref, dict]] = {}  # id -> (the live body, its key parts)


def _forget(i: int) -> Callable[[weakref.ref], None]:
    """Drops a collected body's entry, before its id can be taken by another."""
    return lambda ref: _SEEN.pop(i) if _SEEN.get(i, (None,))[0] is ref else None


class BodyCache:
    """At most `size` values derived from bodies, the least recently used dropped first.
    A value is keyed by `body_key(body, reads)` and the caller's `extra`: whatever else it
    depends on (targets, options)."""

    def __init__(self, reads: Sequence[str] = (), size: int = 64):
        self.reads, self.size = tuple(reads), size
        self._values: OrderedDict = OrderedDict()

    def get(self, body: Body, extra: Hashable, make: Callable[[], T]) -> T:
        """The value kept for (body, extra), else `make()`, kept."""
        key = (body_key(body, self.reads), extra)
        if key in self._values:
            self._values.move_to_end(key)
            return self._values[key]
        value = self._values[key] = make()
        if len(self._values) > self.size:
            self._values.popitem(last=False)
        return value

    def __len__(self) -> int:
        return len(self._values)

    def clear(self) -> None:
        self._values.clear()

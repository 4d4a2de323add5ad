"""A small cache of values built for an object and kept while it lives (the grid sequencing's
hierarchy per Model, the padded multigrid's layout per Topology): both objects are constant once
built, so what is derived from them alone is built once."""

from __future__ import annotations

import weakref
from collections import OrderedDict
from typing import Any, Callable


def per_object(store: OrderedDict, obj, key: Any, build: Callable[[], Any], limit: int):
    """The value ``build()`` made for ``obj`` and ``key`` (compared with ==), kept in ``store`` (an
    OrderedDict by id(obj)) while obj lives; the ``limit`` most recently used objects' are kept.
    A different key for the same object builds and replaces its value."""
    k = id(obj)
    got = store.get(k)
    if got is not None and got[0]() is obj and got[1] == key:
        store.move_to_end(k)
        return got[2]
    value = build()
    if got is None:
        weakref.finalize(obj, store.pop, k, None)
    store[k] = (weakref.ref(obj), key, value)
    while len(store) > limit:
        store.popitem(last=False)
    return value

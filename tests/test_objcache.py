"""objcache.per_object: a value built once per (object, key), dropped with its object, and only
the most recently used kept."""

import gc
from collections import OrderedDict

from clothsim.solvers.newton.objcache import per_object


class _Obj:
    pass


def test_per_object_builds_once_per_object_and_key_and_forgets_dead_objects():
    store, built = OrderedDict(), []

    def get(o, key):
        return per_object(store, o, key, lambda: built.append((id(o), key)) or len(built), 2)

    a, b, c = _Obj(), _Obj(), _Obj()
    assert get(a, 1) == 1 and get(a, 1) == 1  # kept
    assert get(a, 2) == 2 and get(a, 2) == 2  # another key: rebuilt, then kept
    assert get(b, 1) == 3 and len(store) == 2
    get(a, 2)  # a most recently used
    assert get(c, 1) == 4 and len(store) == 2  # b, least recently used, dropped
    assert id(b) not in store and id(a) in store
    del a
    gc.collect()
    assert len(store) == 1  # a's entry went with it

"""The per-body host caches (`diffbody._body_cache`): bounded, least recently used first out,
keyed by the structure and the values of the arrays the data reads, never by a body's id."""

import dataclasses
import gc
import weakref
from collections import OrderedDict

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from diffbody import _body_cache
from diffbody._body_cache import RANGES, BodyCache, body_key
from diffbody.problem._constraints import GEOMETRY, resolve_constraints
from diffbody.problem._targets import Target
from diffbody.problem._tree import tree_layout


def _longer(body, segment: int = 3, by: float = 0.01):
    """The body with one segment `by` metres longer: the same structure, another length."""
    return dataclasses.replace(body, lengths=body.lengths.at[segment].add(by))


@pytest.fixture(scope="module")
def bodies(male50):
    return [male50, _longer(male50), _longer(male50, 5), male50.with_root("left_wrist")]


@given(
    size=st.integers(1, 4),
    calls=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 2)), max_size=40),
)
def test_the_bound_holds_and_the_least_recently_used_goes_first(bodies, size, calls):
    """Against a model LRU of (body, extra): a value is made exactly when the model lacks its
    key, and the cache never holds more than `size`."""
    cache, model, made = BodyCache(("lengths",), size), OrderedDict(), []
    for b, extra in calls:
        value = cache.get(bodies[b], extra, lambda b=b, extra=extra: made.append((b, extra)))
        assert value is None
        if (b, extra) in model:
            model.move_to_end((b, extra))
        else:
            assert made.pop() == (b, extra)
            model[(b, extra)] = None
            if len(model) > size:
                model.popitem(last=False)
        assert not made and len(cache) == len(model) <= size


def test_a_length_parts_what_reads_lengths_only(male50):
    """Two bodies differing in one length: apart where the data reads the lengths (the
    contact constraints' rest overlaps), shared where it does not (the whole tree's layout)."""
    other = _longer(male50, male50.segment_index("left_clavicle"), 0.02)
    assert body_key(male50, GEOMETRY) != body_key(other, GEOMETRY)
    assert body_key(male50, RANGES) == body_key(other, RANGES)
    assert tree_layout(other) is tree_layout(male50)
    arm = [Target.no_contact(["left_upper_arm"])]
    mine = resolve_constraints(male50, arm, male50.rest_pose())
    theirs = resolve_constraints(other, arm, other.rest_pose())
    # the arm stands 2 cm farther out: its rest overlaps with the torso are other
    assert np.abs(np.asarray(mine.allowance) - np.asarray(theirs.allowance)).max() > 1e-3
    assert mine is resolve_constraints(male50, arm, male50.rest_pose())


def test_a_collected_body_leaves_nothing_to_a_body_at_its_id(male50):
    """A body's remembered key goes with it. Then, as if the allocator handed its id to a
    new body of other lengths before the entry went (its parts left at that id, its body
    dead), the new body still gets its own entry."""
    cache, made = BodyCache(("lengths",)), []

    def get(body):
        return cache.get(body, None, lambda: made.append(None) or len(made))

    old = _longer(male50, by=0.02)
    gone, ref = id(old), weakref.ref(old)
    assert get(old) == 1
    parts = dict(_body_cache._SEEN[gone][1])
    del old
    gc.collect()
    assert ref() is None and gone not in _body_cache._SEEN
    new = _longer(male50, by=0.03)
    _body_cache._SEEN[id(new)] = (ref, parts)
    try:
        assert get(new) == 2 and len(cache) == 2
        assert body_key(new, ("lengths",)) != body_key(male50, ("lengths",))
    finally:
        del new
        gc.collect()

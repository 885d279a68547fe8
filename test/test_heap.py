"""The startup heap is moved out of the garbage collector's way once, before the first frame."""

from __future__ import annotations

import gc

import node_support
import pytest

from smplify3d_ros.runtime import heap


def test_frozen_objects_are_no_longer_walked_by_full_collections():
    alive = [object()]  # a container, tracked by the collector
    gc.collect()
    assert any(o is alive for o in gc.get_objects(generation=2))
    try:
        assert heap.freeze_startup_heap() > 0
        assert not any(o is alive for o in gc.get_objects(generation=2)), "still walked at every full collection"
        assert alive[0] is not None  # frozen, not freed
    finally:
        gc.unfreeze()


@pytest.fixture
def freezes(monkeypatch):
    calls: list[int] = []
    monkeypatch.setattr(heap, "freeze_startup_heap", lambda: calls.append(1) or 0)
    return calls


def test_the_replay_freezes_its_startup_heap(freezes):
    from smplify3d_ros.replay import replay_bag

    path = node_support.fixture_bag("sqlite3").path
    replay_bag(path, progress=False, config=node_support.config(), node_config=node_support.node_config(),
               fitter=node_support.fitter())
    assert freezes == [1]


def test_the_node_freezes_its_startup_heap_before_the_worker_starts(ros, freezes):
    from smplify3d_ros.node import create_node

    node = create_node({}, fitter=node_support.fitter())
    try:
        assert freezes == [1]
    finally:
        node.destroy_node()

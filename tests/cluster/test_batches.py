"""service/cluster/batches.py without a cluster: the order in which a request's runs pick
their nodes (rendezvous hashing)."""

from __future__ import annotations

import collections

import pytest
from hypothesis import given
from hypothesis import strategies as st

pytestmark = pytest.mark.cluster

ids = st.text("0123456789abcdef", min_size=8, max_size=8)


@pytest.fixture(scope="module")
def ranked():
    """:func:`service.cluster.batches.ranked` (Ray imported once, outside the examples)."""
    from service.cluster.batches import ranked

    return ranked


@given(meshes=st.lists(ids, min_size=1, max_size=3), nodes=st.sets(ids, min_size=2, max_size=8))
def test_a_node_leaving_moves_only_its_own_place(ranked, meshes, nodes):
    """Every process ranks the same way whatever order it lists the nodes in; without one
    node the others keep their order, so only that node's runs go elsewhere."""
    order = ranked(meshes, nodes)
    assert sorted(order) == sorted(nodes)
    assert ranked(list(reversed(meshes)), sorted(nodes, reverse=True)) == order
    gone = order[0]
    assert ranked(meshes, nodes - {gone}) == [n for n in order if n != gone]


def test_different_meshes_spread_over_the_nodes(ranked):
    """Over 4,000 mesh ids, each of 4 nodes ranks first for about a quarter of them."""
    nodes = [f"node-{k}" for k in range(4)]
    first = collections.Counter(ranked([f"mesh-{m}"], nodes)[0] for m in range(4000))
    assert set(first) == set(nodes)
    assert all(800 < count < 1200 for count in first.values()), first


def test_a_cancel_while_a_task_runs_is_noted_not_raised():
    """Ray cancels a running task by simulating SIGINT in its worker's main thread
    (``_thread.interrupt_main``): inside :class:`_Cancel` that only sets ``requested`` —
    no ``KeyboardInterrupt`` in the middle of a kernel's dispatch — and the handler that
    was there before is back afterwards."""
    import _thread
    import signal

    from service.cluster.batches import _Cancel

    before = signal.getsignal(signal.SIGINT)
    with _Cancel() as cancel:
        assert not cancel.requested
        _thread.interrupt_main()
        for _ in range(1000):  # the handler runs between bytecodes of this thread
            if cancel.requested:
                break
        assert cancel.requested
    assert signal.getsignal(signal.SIGINT) is before
    with pytest.raises(KeyboardInterrupt):  # Python's own handler again
        _thread.interrupt_main()
        for _ in range(1000):
            pass


def test_a_node_that_ends_idle_workers_within_a_minute_is_told_how_to_keep_them():
    """Ray's default (1 s) and anything under a minute is named, with the variable to set;
    the README's value is not."""
    from service.cluster.batches import IDLE_WORKERS, IDLE_WORKERS_MS, idle_worker_warning

    said = idle_worker_warning(1000)
    assert said is not None and "after 1 s" in said and IDLE_WORKERS in said
    assert "after 59.999 s" in idle_worker_warning(59_999)
    assert idle_worker_warning(60_000) is None
    assert idle_worker_warning(IDLE_WORKERS_MS) is None

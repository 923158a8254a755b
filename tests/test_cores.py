"""assetpipe.core.cores: helper threads only on cores no task of the build needs."""

from __future__ import annotations

import multiprocessing
import threading
import time

import pytest

from assetpipe.core import cores


@pytest.fixture
def spare():
    """A shared counter installed in this process (as a pool worker's initializer does), and
    uninstalled afterwards."""
    counter = cores.SpareCores(multiprocessing.get_context(), 0)
    cores.install(counter.value)
    yield counter.value
    cores.install(None)


#: how long the calling thread's first item waits for a helper to start one (``await_helper``):
#: a bound for a starved machine, not a delay (it ends as soon as a helper runs)
HELPER_WAIT_S = 10.0


def _recorder(delay: float = 0.0, on_helper=None, await_helper: bool = False):
    """fn(x) -> x * x, recording which thread ran each item. ``await_helper``: the calling
    thread's first item waits (at most HELPER_WAIT_S) until a helper thread has started an item,
    so that a test of helpers does not depend on how soon the machine schedules one."""
    ran: dict[int, int] = {}
    main = threading.get_ident()
    helper_started = threading.Event()
    waited: list[int] = []

    def fn(x: int) -> int:
        me = threading.get_ident()
        ran[x] = me
        if me != main:
            helper_started.set()
            if on_helper is not None:
                on_helper(x)
        elif await_helper and not waited:
            waited.append(x)  # only the first item waits
            helper_started.wait(HELPER_WAIT_S)
        time.sleep(delay)
        return x * x

    return fn, ran, main


def test_without_a_counter_items_run_on_up_to_the_threads_asked_in_order():
    fn, ran, _ = _recorder(delay=0.01)
    assert cores.map_spare(fn, list(range(12)), 3) == [x * x for x in range(12)]
    assert 1 < len(set(ran.values())) <= 3


def test_one_thread_or_one_item_runs_here():
    fn, ran, main = _recorder()
    assert cores.map_spare(fn, [1, 2, 3], 1) == [1, 4, 9]
    assert cores.map_spare(fn, [5], 4) == [25]
    assert set(ran.values()) == {main}


def test_no_spare_core_means_no_helper(spare):
    """Every worker busy (the counter at 0, or below while tasks wait in the queue): the items
    all run on the calling thread."""
    for value in (0, -2):
        spare.value = value
        fn, ran, main = _recorder(delay=0.005)
        assert cores.map_spare(fn, list(range(8)), 4) == [x * x for x in range(8)]
        assert set(ran.values()) == {main}
        assert spare.value == value


def test_a_spare_core_is_used_and_given_back(spare):
    spare.value = 1
    fn, ran, main = _recorder(delay=0.02, await_helper=True)
    assert cores.map_spare(fn, list(range(10)), 2) == [x * x for x in range(10)]
    assert len(set(ran.values())) == 2  # a helper took some of the items
    deadline = time.monotonic() + 2.0  # its core comes back once it has run out of items
    while spare.value != 1 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert spare.value == 1


def test_a_helper_gives_its_core_back_when_a_task_is_handed_out(spare):
    """A task handed to the pool meanwhile (the counter goes below 0): the helper finishes its
    item, gives the core back and takes no more; the rest run on the calling thread."""
    spare.value = 1

    def hand_out_a_task(_x):
        with spare.get_lock():
            spare.value -= 1

    fn, ran, main = _recorder(delay=0.02, on_helper=hand_out_a_task, await_helper=True)
    assert cores.map_spare(fn, list(range(10)), 2) == [x * x for x in range(10)]
    helpers = [x for x, t in ran.items() if t != main]
    assert len(helpers) == 1
    deadline = time.monotonic() + 2.0
    while spare.value != 0 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert spare.value == 0  # the task still holds its core; the helper's is back


@pytest.mark.parametrize("installed", [False, True])
def test_an_item_that_raises_raises_from_map_spare(installed, request):
    if installed:
        request.getfixturevalue("spare").value = 1

    def fn(x: int) -> int:
        time.sleep(0.005)
        if x == 3:
            raise ValueError("item 3")
        return x

    with pytest.raises(ValueError, match="item 3"):
        cores.map_spare(fn, list(range(10)), 2)


def test_the_pool_counts_each_task_until_it_ends():
    """The build's executor: a task handed out takes a core, its end gives it back."""
    from assetpipe.graph import Executor

    ex = Executor(2)
    try:
        futures = [ex.submit((time.sleep, 0.2)) for _ in range(3)]
        assert ex._spare.value.value == 2 - 3
        for f in futures:
            ex.outcome(f)
        deadline = time.monotonic() + 2.0
        while ex._spare.value.value != 2 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert ex._spare.value.value == 2
    finally:
        ex.close()

"""The time budget counts CPU seconds of the process, not the wall clock (issue 19)."""

import time

import pytest

from dcmotor_id.core.progress import budget_clock, Progress, TimeBudgetExceeded


def test_waiting_spends_no_budget():
    # On a loaded machine the process waits for a core: a wall-clock budget ran out at a third
    # of the work (HSM150, twelve records) and the answer depended on the load.
    progress = Progress(max_time_s=0.2)
    time.sleep(0.4)
    progress(cost=1.0)  # the wall clock is past the budget, the CPU time is not
    assert not progress.expired() and progress.remaining() > 0.0
    assert progress.elapsed() >= 0.4  # the status line and elapsed_s stay wall clock


def test_computing_spends_it():
    progress = Progress(max_time_s=0.2)
    start = budget_clock()
    while budget_clock() - start < 0.3:
        sum(range(1000))
    assert progress.expired()
    with pytest.raises(TimeBudgetExceeded, match='CPU'):
        progress(cost=1.0)

"""Longest-predicted-first task order for dynamic executors (jaxabc.executors.scheduling)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import jaxabc
from jaxabc.examples import busy_child_simulate, sleep_simulate
from jaxabc.executors import task_durations
from jaxabc.executors.scheduling import (
    NearestNeighbourCost,
    dispatch_order,
    dynamic_makespan,
    get_cost_model,
    longest_predicted_first,
    lower_bound,
    static_makespan,
    tight_lower_bound,
)


def test_nearest_neighbour_cost_learns_a_duration_that_depends_on_theta():
    rng = np.random.default_rng(0)
    # Two regimes as in water: "vaporised" parameters are fast, "liquid" ones slow, plus noise.
    x = rng.uniform(0, 1, size=(400, 2))
    t = np.where(x[:, 0] > 0.6, 2.0, 10.0) * rng.lognormal(0.0, 0.2, 400)
    slow = x[300:, 0] < 0.55
    fast = x[300:, 0] > 0.65
    mean = NearestNeighbourCost(k=5, min_history=16, aggregate="mean")
    assert mean.predict(x[:5]) is None  # no history yet: no opinion
    mean.observe(x[:300], t[:300])
    pred = mean.predict(x[300:])
    assert np.all(pred[slow] > 6.0) and np.all(pred[fast] < 3.5)
    # The default is pessimistic: the longest neighbour.  Never below the mean; fast tasks near
    # the regime boundary are ranked with the slow ones, fast tasks far from it stay fast.
    worst = NearestNeighbourCost(k=5, min_history=16)
    worst.observe(x[:300], t[:300])
    high = worst.predict(x[300:])
    assert np.all(high >= pred * (1 - 1e-12))
    assert np.all(high[slow] > 6.0) and np.all(high[x[300:, 0] > 0.75] < 3.5)
    near = (x[300:, 0] > 0.6) & (x[300:, 0] < 0.62)
    assert near.any() and np.all(high[near] > 6.0)


def test_dispatch_order_is_longest_predicted_first_and_stable():
    model = NearestNeighbourCost(k=1, min_history=2)
    model.observe(np.array([[0.0], [1.0], [2.0]]), np.array([1.0, 5.0, 3.0]))
    order = dispatch_order(model, np.array([[0.1], [2.1], [0.9], [1.1], [-0.2]]))
    assert order.tolist() == [2, 3, 1, 0, 4]  # 5, 5, 3, 1, 1 s: ties keep their order
    assert dispatch_order(None, np.zeros((3, 1))).tolist() == [0, 1, 2]


def test_bad_order_options():
    with pytest.raises(ValueError, match="longest_first"):
        get_cost_model("shortest")
    with pytest.raises(TypeError, match="predict"):
        get_cost_model(42)
    with pytest.raises(ValueError, match="min_history"):
        NearestNeighbourCost(k=0)
    with pytest.raises(ValueError, match="aggregate"):
        NearestNeighbourCost(aggregate="median")
    with pytest.raises(ValueError, match="dynamic"):
        jaxabc.MPIExecutor("static", order="longest_first")


def test_process_pool_hands_out_the_longest_predicted_task_first():
    """One worker runs tasks one by one, so finish times give the order it got them in."""
    # k = 1: each task is predicted by its own earlier run; durations 50 ms apart, far above the
    # timing jitter of a busy machine.
    ex = jaxabc.ProcessPoolExecutor(max_workers=1, order=NearestNeighbourCost(k=1, min_history=16))
    try:
        durations = np.array([0.05, 0.3, 0.1, 0.2, 0.15, 0.0, 0.35, 0.25] * 2)[:, None]
        keys = np.zeros((durations.shape[0], 2), np.uint32)
        first = ex.map(sleep_simulate, keys, durations)  # no history yet: task order
        np.testing.assert_array_equal(np.argsort(first.summaries[:, 1]), np.arange(durations.shape[0]))
        second = ex.map(sleep_simulate, keys, durations[::-1])
        ran = second.summaries[np.argsort(second.summaries[:, 1]), 0]
        assert np.all(np.diff(ran) <= 0), ran  # longest first
        # Results are in task order whatever the run order.
        np.testing.assert_array_equal(second.summaries[:, 0], durations[::-1, 0])
    finally:
        ex.close()


def test_order_never_changes_a_run():
    prior = jaxabc.Uniform([-5.0], [5.0], names=("mu",))
    kwargs = dict(num_particles=20, num_steps=2, seed=3)
    runs = []
    for order in ("fifo", "longest_first"):
        ex = jaxabc.ProcessPoolExecutor(max_workers=2, order=order)
        try:
            runs.append(
                jaxabc.run(
                    "apmcabc", jaxabc.examples.host_gaussian_simulate, prior, np.array([0.5]), executor=ex, **kwargs
                )
            )
        finally:
            ex.close()
    np.testing.assert_array_equal(runs[0].particles, runs[1].particles)
    np.testing.assert_array_equal(runs[0].weights, runs[1].weights)


def test_cpu_time_counts_the_programs_a_task_starts_and_sleep_is_costed_by_wall_time():
    """CPU time is the load-independent cost of a computing task (here spent in a child
    process, as ``gmx mdrun`` is); a task that sleeps costs its wall time."""
    ex = jaxabc.ProcessPoolExecutor(max_workers=1)
    try:
        keys = np.zeros((2, 2), np.uint32)
        busy = ex.map(busy_child_simulate, keys, np.array([[0.4], [0.8]]))
        # The child's busy loop plus an interpreter start-up (< 0.5 s CPU even on a slow disk).
        assert np.all(busy.cpu_time >= [0.4, 0.8]) and np.all(busy.cpu_time < [0.9, 1.3]), busy.cpu_time
        np.testing.assert_array_equal(task_durations(busy.wall_time, busy.cpu_time), busy.cpu_time)
        idle = ex.map(sleep_simulate, keys, np.array([[0.3], [0.3]]))
        assert np.all(idle.wall_time >= 0.3) and np.all(idle.cpu_time < 0.03), idle.cpu_time
        np.testing.assert_array_equal(task_durations(idle.wall_time, idle.cpu_time), idle.wall_time)
    finally:
        ex.close()
    serial = jaxabc.SerialExecutor().map(busy_child_simulate, keys[:1], np.array([[0.3]]))
    assert 0.3 <= serial.cpu_time[0] < 0.8


def test_lower_bounds_hold_and_the_tight_one_is_reached_on_small_cases():
    """The bounds against the optimal makespan found by brute force.

    Every assignment of up to 8 tasks to 2-3 workers is tried: no schedule beats either bound,
    and the pigeonhole bound is exactly the optimum on some instances where the plain
    ``max(total / n, longest)`` is not (so it is the one to judge a scheduler against).
    """
    rng = np.random.default_rng(3)
    tight_is_optimal_where_plain_is_not = 0
    for _ in range(60):
        m, n = int(rng.integers(3, 9)), int(rng.integers(2, 4))
        d = rng.lognormal(0.0, 0.6, m)
        optimum = min(
            max(np.bincount(a, weights=d, minlength=n)) for a in map(np.array, itertools.product(range(n), repeat=m))
        )
        plain, tight = lower_bound(d, n), tight_lower_bound(d, n)
        assert plain <= tight * (1 + 1e-12) and tight <= optimum * (1 + 1e-12)
        for schedule in (
            dynamic_makespan(d, n),
            static_makespan(d, n),
            dynamic_makespan(longest_predicted_first(d, d), n),
        ):
            assert schedule >= optimum * (1 - 1e-12)
        tight_is_optimal_where_plain_is_not += bool(np.isclose(tight, optimum) and plain < optimum - 1e-9)
    assert tight_is_optimal_where_plain_is_not >= 5


def test_makespans_on_cases_worked_by_hand():
    # Greedy in task order: 3 and 1 start; 1 ends, 2 starts at 1 -> ends 3; 2 starts at 3 -> 5.
    d = np.array([3.0, 1.0, 2.0, 2.0])
    assert dynamic_makespan(d, 2) == 5.0
    assert dynamic_makespan(d, 2, overhead=0.5) == 6.0  # 3.5 | 1.5 + 2.5 = 4 | 3.5 + 2.5 = 6
    # Longest first: 3 | 2, 2 at 2 -> 4 | 1 at 3 -> 4; LPT reaches total / n here.
    assert longest_predicted_first(d, d).tolist() == [3.0, 2.0, 2.0, 1.0]
    assert dynamic_makespan(longest_predicted_first(d, d), 2) == 4.0 == lower_bound(d, 2)
    # Static: chunks [3, 1] and [2, 2]; a per-chunk overhead is paid once.
    assert static_makespan(d, 2) == 4.0 and static_makespan(d, 2, overhead=1.0) == 5.0
    # More workers than tasks: the longest task.
    assert dynamic_makespan(d, 8) == static_makespan(d, 8) == 3.0
    # m = n + 1 equal tasks: two share a worker, twice the plain bound; the tight bound sees it.
    ones = np.ones(5)
    assert lower_bound(ones, 4) == 1.25 and tight_lower_bound(ones, 4) == 2.0 == dynamic_makespan(ones, 4)
    # Ties in the prediction keep the task order.
    assert longest_predicted_first([1.0, 2.0, 3.0], [5.0, 5.0, 9.0]).tolist() == [3.0, 1.0, 2.0]


def test_makespan_inputs_are_checked():
    with pytest.raises(ValueError, match="at least one task"):
        lower_bound(np.array([]), 2)
    with pytest.raises(ValueError, match="at least one worker"):
        dynamic_makespan(np.ones(3), 0)
    with pytest.raises(ValueError, match="one prediction per duration"):
        longest_predicted_first(np.ones(3), np.ones(2))

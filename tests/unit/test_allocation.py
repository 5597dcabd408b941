"""A steady-state filter step allocates no numpy array: counted in numpy's tracemalloc domain over
thousands of steps covering every fusion (accelerometer, barometer, heading, taut constraints)."""

import tracemalloc

import numpy as np
import pytest

from balloon_core.config import Design
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.outputs import WindCovOutput
from firmware_py.estimator.state import MODE_TAUT, FilterConfig
from tests.helpers.flights import feed, stream
from tests.helpers.numpy_alloc import count_allocations


def numpy_allocations(fn) -> tuple[int, int]:
    """(number, bytes) of numpy data allocations made by fn() that are still alive or were made."""
    domain = np.lib.tracemalloc_domain
    tracemalloc.start()
    try:
        before = tracemalloc.take_snapshot().filter_traces([tracemalloc.DomainFilter(True, domain)])
        fn()
        after = tracemalloc.take_snapshot().filter_traces([tracemalloc.DomainFilter(True, domain)])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    stats = after.compare_to(before, "traceback")
    return sum(s.count_diff for s in stats if s.count_diff > 0), peak


@pytest.mark.slow
@pytest.mark.parametrize("float32", [False, True])
def test_steady_state_steps_allocate_no_numpy_arrays(float32):
    samples, _ = stream("paper-reference", 300.0, 11)
    est = Estimator(Design(), FilterConfig(float32=float32))
    out = WindCovOutput(100.0, 0.0)
    feed(est, samples[:12000])
    assert est.ekf.mode == MODE_TAUT
    # 4000 steps: 800 baro, 400 heading, 800 taut fusions
    count, _ = numpy_allocations(steps_over(est, out, samples[12000:16000]))
    assert est.baro_status.fused > 0 and est.heading_status.fused > 0 and est.taut_status[2].fused > 0
    assert count == 0
    # and not even a temporary that was freed again (counted by an allocator hook)
    assert count_allocations(steps_over(est, out, samples[16000:20000])) == 0


def steps_over(est, out, window):
    def steps():
        for s in window:
            if s.baro:
                est.on_baro(s.time_usec, *s.baro)
            est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
            out.update(est, s.time_usec)
            out.fields(est)

    return steps


def test_the_counters_see_allocations():
    """The instruments work: a kept array and a freed temporary are both seen."""
    a = np.ones(15)
    keep = []
    count, _ = numpy_allocations(lambda: keep.append(a * 2.0))
    assert count >= 1
    assert count_allocations(lambda: np.add(a, a).sum()) >= 1
    out = np.empty(15)
    assert count_allocations(lambda: np.add(a, a, out=out)) == 0

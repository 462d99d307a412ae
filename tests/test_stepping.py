"""The shared run loop: argument checks, recording cadence, failures passing through."""

import pytest
from licrom.errors import ConfigError, SolverError
from licrom.stepping import record_run


class Counter:
    def __init__(self, fail_at=None):
        self.t = 0.0
        self.fail_at = fail_at

    def step(self):
        if self.fail_at is not None and self.t >= self.fail_at:
            raise SolverError("no convergence", iterations=3, residual=1.0)
        self.t += 0.5
        return 2, 1e-7, True


def test_frames_are_recorded_every_record_every_steps():
    c = Counter()
    rec = record_run(c.step, lambda: c.t, lambda: c.t, 7, record_every=3)
    assert rec.frames == [0.0, 1.5, 3.0] and rec.times == rec.frames
    assert rec.iterations == [2] * 7 and all(rec.converged) and len(rec.seconds) == 7
    arrays = rec.arrays()
    assert arrays["iterations"].dtype.kind == "i" and arrays["converged"].dtype == bool


@pytest.mark.parametrize("steps, every", [(True, 1), (-1, 1), (2.0, 1), (3, 0), (3, False)])
def test_bad_arguments_are_named(steps, every):
    with pytest.raises(ConfigError, match=r"steps|record_every"):
        record_run(Counter().step, lambda: 0, lambda: 0.0, steps, every)


def test_a_failing_step_passes_through_with_the_progress_bar_closed():
    c = Counter(fail_at=1.0)
    with pytest.raises(SolverError) as info:
        record_run(c.step, lambda: c.t, lambda: c.t, 5, progress=True)
    assert info.value.iterations == 3 and c.t == 1.0

"""The shared run loop: argument checks, recording cadence, failures passing through."""

import pytest
from licrom.errors import ConfigError, SolverError
from licrom.stepping import IMPACT_FRAMES_PER_FRAME, record_run


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


def test_impact_frames_are_the_steps_between_frames_just_after_each_impact():
    # deepest penetration after each step 1..16: impacts (none -> some) at steps 3 and 9
    depth = [0.0, 0.0, 1e-4, 2e-4, 1e-4, 0.0, 0.0, 0.0, 3e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4]
    c = Counter()
    probe = lambda: (1.0, depth[round(c.t / 0.5) - 1])  # noqa: E731
    rec = record_run(c.step, lambda: c.t, lambda: c.t, 16, record_every=4, validity=probe, impact_window=3)
    steps = [round(t / 0.5) for t in rec.impact_times]
    assert steps == [3, 5, 9, 10, 11]  # steps 3-5 and 9-11, less the regular frame at step 4
    assert rec.impact_frames == rec.impact_times and [round(t / 0.5) for t in rec.times] == [0, 4, 8, 12, 16]
    c = Counter()
    assert record_run(c.step, lambda: 0, lambda: 0.0, 16, 4, validity=probe).impact_frames == []


def test_a_run_that_starts_in_contact_counts_its_first_step_as_an_impact_and_a_bad_window_is_named():
    c = Counter()
    rec = record_run(c.step, lambda: c.t, lambda: c.t, 6, record_every=3, validity=lambda: (1.0, 1e-4), impact_window=2)
    assert [round(t / 0.5) for t in rec.impact_times] == [1, 2]
    for bad in (-1, 1.5, True):
        with pytest.raises(ConfigError, match="impact_window"):
            record_run(Counter().step, lambda: 0, lambda: 0.0, 3, 1, impact_window=bad)


def test_a_run_keeps_at_most_two_impact_frames_per_regular_frame():
    c = Counter()
    touching = lambda: (1.0, 1e-4 if round(c.t / 0.5) % 2 else 0.0)  # noqa: E731  an impact at every other step
    rec = record_run(c.step, lambda: c.t, lambda: c.t, 40, record_every=10, validity=touching, impact_window=5)
    assert IMPACT_FRAMES_PER_FRAME == 2 and len(rec.frames) == 5
    assert [round(t / 0.5) for t in rec.impact_times] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 11]

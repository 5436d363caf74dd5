"""The closed loop a user owns: stepping it by hand is the same run as ``simulate``; observers are
called in order once per frame; the loop refuses to step when it is not running."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.interfaces import Command, Controller, StepStats
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import ClosedLoop, Frame, Observer, simulate

SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0]]), False, 0.02)
WALL_COLUMNS = {"solve_ms", "controller_ms"}


class Recorder(Observer):
    """Records every hook call as (hook, frame index)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int]] = []
        self.ended_with: dict | None = None

    def on_reset(self, loop):
        self.calls.append(("on_reset", loop.next_frame))

    def frame_start(self, loop, frame):
        assert frame.measurement is None and frame.command is None
        self.calls.append(("frame_start", frame.index))

    def before_controller(self, loop, frame):
        assert frame.measurement is not None and frame.command is None
        self.calls.append(("before_controller", frame.index))

    def after_controller(self, loop, frame):
        assert frame.command is not None and frame.step_s >= 0
        self.calls.append(("after_controller", frame.index))

    def frame_end(self, loop, frame):
        ended = sum(1 for name, _ in self.calls if name == "frame_end")
        assert loop.log.n == ended + 1  # the frame's row is logged before frame_end
        self.calls.append(("frame_end", frame.index))

    def on_end(self, loop, metrics):
        self.ended_with = dict(metrics)
        metrics["observed_frames"] = sum(1 for name, _ in self.calls if name == "frame_end")


def test_stepping_by_hand_is_the_run_simulate_makes(scenario):
    path = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.02]]), False, 0.04)  # a corner
    # a short settle and tail: the run ends 0.5 s after 1.25 x the path's time (not the whole rectangle)
    scenario = scenario.model_copy(
        update={"sim": scenario.sim.model_copy(update={"settle_s": 0.5, "tail_s": 0.5})}
    )
    ref = simulate(scenario, "follow", path, seed=3)
    loop = ClosedLoop(scenario, "follow", path, seed=3)
    loop.reset()
    frames: list[Frame] = []
    while not loop.done:
        frames.append(loop.step())
    res = loop.result()
    assert len(frames) == len(res.log["t_s"]) == len(ref.log["t_s"])
    for name in set(ref.log) - WALL_COLUMNS:
        np.testing.assert_array_equal(res.log[name], ref.log[name], err_msg=name)
    timed = {k for k in ref.metrics if "_ms" in k}
    np.testing.assert_equal(
        {k: v for k, v in res.metrics.items() if k not in timed},
        {k: v for k, v in ref.metrics.items() if k not in timed},
    )  # NaN (no arrival) equals NaN here
    # each frame's row is the logged row, its time on the camera grid
    np.testing.assert_array_equal([f.t_s for f in frames], res.log["t_s"])
    assert [f.index for f in frames] == list(range(frames[0].index, frames[0].index + len(frames)))
    assert frames[0].t_s < 0 <= frames[-1].t_s  # the settle phase comes first


def test_observers_are_called_in_order_once_per_frame(scenario):
    rec = Recorder()
    res = ClosedLoop(scenario, "follow", SHORT, seed=0).run([rec])
    n = len(res.log["t_s"])
    assert rec.calls[0][0] == "on_reset"
    hooks = ["frame_start", "before_controller", "after_controller", "frame_end"]
    body = rec.calls[1:]
    assert len(body) == 4 * n
    for i in range(n):
        names = [name for name, _ in body[4 * i : 4 * i + 4]]
        indices = {index for _, index in body[4 * i : 4 * i + 4]}
        assert names == hooks and len(indices) == 1
    assert res.metrics["observed_frames"] == n  # on_end may add to the metrics
    assert rec.ended_with is not None and "tracking_rms_mm" in rec.ended_with


class Explode(Controller):
    """Pushes so hard the capsule decouples."""

    name = "explode"

    def reset(self, scenario, path, epm_position_m):
        pass

    def step(self, t_s, measurement, epm_position_m):
        return Command(np.array([0.0, 0.2 if t_s >= 0 else 0.0, 0.0]), StepStats())


def test_a_failure_frame_ends_the_run_and_calls_frame_end_without_a_command(scenario):
    rec = Recorder()
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["friction"]["mu0"] = 1.5  # the capsule cannot follow: it decouples
    from capsule_mpc.config import config_from_dict

    res = ClosedLoop(config_from_dict(data), Explode(), SHORT, seed=0).run([rec])
    assert res.flags.decoupled and rec.calls[-1][0] == "frame_end"
    assert rec.calls[-2][0] == "frame_end"  # the failure frame skips the controller's hooks


def test_the_loop_refuses_to_step_before_reset_and_after_the_end(scenario):
    loop = ClosedLoop(scenario, "follow", SHORT, seed=0)
    with pytest.raises(RuntimeError, match="reset"):
        loop.step()
    loop.reset()
    while not loop.done:
        loop.step()
    with pytest.raises(RuntimeError, match="over"):
        loop.step()
    assert loop.result().flags.at_rest


def test_run_outcome_says_how_each_run_ended(scenario):
    from capsule_mpc.config import config_from_dict
    from capsule_mpc.sim import RunOutcome

    done = ClosedLoop(scenario, "follow", SHORT, seed=0).run()
    assert done.flags.outcome is RunOutcome.COMPLETED and not done.failed
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["friction"]["mu0"] = 1.5
    lost = ClosedLoop(config_from_dict(data), Explode(), SHORT, seed=0).run()
    assert lost.flags.outcome is RunOutcome.DECOUPLED and lost.failed
    loop = ClosedLoop(scenario, "follow", SHORT, seed=0)
    loop.reset()
    loop.step()
    assert loop.flags.outcome is RunOutcome.RUNNING


def test_step_outcomes_agree_with_the_logged_status(scenario):
    from capsule_mpc.interfaces import StepOutcome

    res = ClosedLoop(scenario, "mpc", SHORT, seed=0).run()
    outcomes = [s.outcome for s in res.step_stats]
    assert outcomes[0] is StepOutcome.NO_MEASUREMENT  # one frame of camera latency
    assert StepOutcome.SOLVED in outcomes
    for stats in res.step_stats:
        assert stats.failed == (stats.outcome in (StepOutcome.LATE, StepOutcome.FAILED, StepOutcome.INVALID))
        if stats.outcome in (StepOutcome.LATE, StepOutcome.FAILED, StepOutcome.PLACE):
            assert stats.status.startswith(stats.outcome.value)

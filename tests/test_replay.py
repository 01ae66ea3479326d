"""Replay (bit-for-bit comparison, first divergence) and the HIL-style runner (controller in
its own process over a pipe at the real 5 Hz clock).

The mechanics are tested with the dissertation's PID steering controller (offline.sim.experiments),
which satisfies the same step() contract as rtctl's Controller; the committed rtctl recordings
of the three section 7.3 scenarios are replayed in test_replay_rtctl_recordings.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from offline.sim.experiments import PidSteeringController, build_controller, run_drive, scenario_by_name
from offline.sim.simulator import RoverSimulator
from rtctl.hil import HilError, run_hil
from rtctl.recording import Recorder, compare_provenance, provenance, read_recording
from rtctl.replay import ReplayError, compare_commands, replay

DATA = Path(__file__).parent / "data"


@functools.lru_cache(maxsize=1)
def _stuck_controller() -> PidSteeringController:
    return build_controller("ff+fb", scenario_by_name("rr_steer_stuck_50"))  # type: ignore[return-value]


def _pid_factory() -> PidSteeringController:
    """Module-level (picklable) factory for the controller process."""
    return _stuck_controller()


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    sc = scenario_by_name("rr_steer_stuck_50")
    path = tmp_path_factory.mktemp("rec") / "stuck.mcap"
    with Recorder(path, {"scenario": sc.name}, truth=True) as rec:
        run_drive(RoverSimulator(sc, seed=2), _stuck_controller(), distance=0.1, recorder=rec)
    return path


def test_replay_is_bit_for_bit(recording):
    rep = replay(recording, _stuck_controller())
    assert rep.identical and rep.first_divergence is None and rep.steps > 10
    assert rep.step_times["steps"] == rep.steps and rep.step_times["over_deadline"] == 0
    assert "identical bit for bit" in rep.summary()


def test_replay_reports_first_divergence(recording):
    rec = read_recording(recording)
    # a controller whose PID is a little stronger
    other = _stuck_controller()
    changed = PidSteeringController.__new__(PidSteeringController)
    changed.__dict__.update(other.__dict__)
    changed.pid = replace(other.pid, kp_yaw=other.pid.kp_yaw * 1.01)
    changed.reset()
    rep = replay(rec, changed)
    assert not rep.identical and rep.diverged_steps > 0
    d = rep.first_divergence
    assert d.field in ("rim_speed", "steer_angle") and d.wheel in ("FR", "FL", "RR", "RL")
    assert d.t == rec.measurements[d.index].t and d.seq == rec.measurements[d.index].seq and d.recorded != d.replayed
    assert all(compare_commands(i, rec.commands[i], rep.commands[i]) is None for i in range(d.index))
    # the comparison is on bits: -0.0 and 0.0 differ
    c = rec.commands[0]
    z = replace(c, steer_angle=(c.steer_angle[0], c.steer_angle[1], c.steer_angle[2], -0.0 if c.steer_angle[3] == 0 else -c.steer_angle[3]))
    assert compare_commands(0, c, z).field == "steer_angle"


def test_replay_errors(recording, tmp_path):
    rec = read_recording(recording)
    rec.commands = rec.commands[:3]
    with pytest.raises(ReplayError, match="measurements but only 3 commands"):
        replay(rec, _stuck_controller())


def test_hil_open_loop_from_recording(recording):
    rec = read_recording(recording)
    ms = rec.measurements[:6]
    rep = run_hil(_pid_factory, measurements=ms, start_method="fork")
    assert rep.ticks == 6 and len(rep.commands) == 6
    # late or not, every reply is collected; the commands are those of the recording, bit for bit
    assert all(compare_commands(i, rec.commands[i], c) is None for i, c in enumerate(rep.commands))
    st = rep.stats()
    assert st["deadline_misses"] == len(rep.late_seqs) and st["step"]["steps"] == 6


SLOW_SEQ = 2
"""The sequence number at which :class:`_SlowOnce` answers late on any machine."""


class _SlowOnce:
    """The PID controller, answering the measurement of :data:`SLOW_SEQ` 0.6 s late (three
    deadlines of 0.2 s): a miss that does not depend on the machine's speed or load."""

    def __init__(self) -> None:
        self.inner = _stuck_controller()

    def step(self, m):
        out = self.inner.step(m)
        if m.seq == SLOW_SEQ:
            time.sleep(0.6)
        return out


def _slow_factory() -> _SlowOnce:
    return _SlowOnce()


class _RecordingPlant:
    """A simulator that remembers the commands applied before each advance."""

    def __init__(self, sim: RoverSimulator) -> None:
        self.sim, self.applied, self.seqs = sim, [], []

    def measure(self):
        m = self.sim.measure()
        self.seqs.append(m.seq)
        return m

    def apply(self, c) -> None:
        self.applied.append(c)
        self.sim.apply(c)

    def advance(self, seconds: float) -> None:
        self.sim.advance(seconds)


def test_hil_closed_loop_with_simulator():
    """A late reply is counted with its sequence number, and the plant keeps the last on-time
    commands over that tick (the servos hold them); an on-time reply is applied. Which other ticks
    are late depends on the machine's load, so the test checks the bookkeeping of every tick, not a
    count: whatever the load, the slow tick is late, each late tick applied the held commands and
    each on-time tick its own reply."""
    sc = scenario_by_name("rr_steer_stuck_50")
    sim = RoverSimulator(sc, seed=4)
    ctl = _stuck_controller()
    c0, _ = ctl.step(run_drive.__globals__["_first_measurement"](sim))
    sim.start(c0)
    plant = _RecordingPlant(sim)
    rep = run_hil(_slow_factory, plant=plant, ticks=5, start_method="fork")
    assert rep.ticks == 5 and sim.t == pytest.approx(1.0) and len(rep.commands) == 5
    assert SLOW_SEQ in rep.late_seqs and rep.deadline_misses == len(rep.late_seqs) >= 1
    assert set(rep.late_seqs) <= set(plant.seqs)
    held, k = None, 0
    for seq, cmd in zip(plant.seqs, rep.commands):
        if seq in rep.late_seqs:
            if held is not None:  # the held commands went to the plant again, not the late reply
                assert plant.applied[k] is held
                k += 1
        else:
            assert plant.applied[k] is cmd
            held, k = cmd, k + 1
    assert k == len(plant.applied)
    assert all(math.isfinite(x) for c in rep.commands for x in c.rim_speed)


def test_hil_errors():
    with pytest.raises(HilError, match="exactly one source"):
        run_hil(_pid_factory)
    with pytest.raises(HilError, match="controller factory failed"):
        run_hil(_broken_factory, measurements=[], start_method="fork")


def _broken_factory():
    raise ValueError("no tables here")


RECORDINGS = sorted(DATA.glob("rec_*.mcap"))


def test_committed_recordings_exist():
    assert len(RECORDINGS) >= 3, "regenerate with: python tests/data/make_recordings.py"
    scen = {read_recording(p).metadata["scenario"] for p in RECORDINGS}
    assert {"rr_trench_clean", "rr_speed_cap_half", "rr_steer_stuck_50"} <= scen


def qp_tolerance(ctl) -> float:
    """How far two solves of the same QP from inputs that differ in their last bits may land apart,
    in command units: OSQP stops at ``eps`` in the QP's scaled variables, i.e. ``eps`` times each
    variable's scale (omega's times the command radius for a rim speed, beta's for a steering
    angle); ten times that, for the warm start's history. (The committed recordings, made on
    another machine, replay here within 8.7e-8; the bound is 1e-5-ish.)"""
    prep = ctl._prep
    sx = np.asarray(prep.allocator.sx, dtype=float)
    rim = float(np.max(sx[prep.idx.om])) * ctl.wheel_radius
    steer = float(np.max(sx[prep.idx.be]))
    return 10.0 * ctl.config.qp.eps * max(rim, steer)


@pytest.mark.parametrize("path", RECORDINGS, ids=[p.stem for p in RECORDINGS])
def test_replay_committed_recording(path):
    """Any change that alters the controller's commands on these drives fails here; if the change
    is intended, regenerate the recordings: python tests/data/make_recordings.py

    Bit for bit where the recording's provenance says this machine and these versions made it;
    elsewhere (another CPU, numpy or osqp: the last bits of a float differ) within the QP's own
    tolerance (:func:`qp_tolerance`), and the replay says by name what differs."""
    rec = read_recording(path)
    kind = rec.metadata["controller"]
    sc = scenario_by_name(rec.metadata["scenario"])
    if kind == "rtctl":
        from offline.sim.rtctl_bridge import rtctl_factory

        ctl = rtctl_factory(str(DATA / "tables"))(sc)
    else:
        ctl = build_controller(kind, sc)
    refuse, warn = compare_provenance(rec.provenance, provenance(ctl))
    assert not refuse, refuse  # the same tables and configuration, whatever the machine
    if warn:
        rep = replay(rec, ctl, rtol=0.0, atol=qp_tolerance(ctl))
    else:
        rep = replay(rec, ctl)
    assert rep.identical, (f"{path.name}: {rep.summary()} (provenance: {warn}; regenerate if intended: "
                           "python tests/data/make_recordings.py)")
    assert len(rec.truth) == rep.steps and rec.timing and rec.diagnostics


def test_hil_rtctl_in_its_own_process_matches_the_recording():
    """rtctl's Controller built from files in a freshly spawned process, fed a committed
    recording at 5 Hz over a pipe: every command equals the recorded one bit for bit (the
    controller runs at the configured target speed of the recording's scenario, 3 cm/s); within
    the QP's tolerance where the provenance says another machine or versions made it."""
    from rtctl.hil import load_controller

    path = DATA / "rec_rr_steer_stuck_50_rtctl.mcap"
    rec = read_recording(path)
    factory = functools.partial(load_controller, str(DATA / "tables" / "index.json"))
    here = factory()
    refuse, warn = compare_provenance(rec.provenance, provenance(here))
    assert not refuse, refuse
    atol = qp_tolerance(here) if warn else None
    rep = run_hil(factory, measurements=rec.measurements[:5], start_method="spawn")
    assert rep.ticks == 5
    assert all(compare_commands(i, rec.commands[i], c, 0.0 if warn else None, atol) is None
               for i, c in enumerate(rep.commands))
    assert rep.stats()["step"]["steps"] == 5

"""Per-wheel actuator terms in the drive library, screened (issue 24).

The library's per-wheel terms (``speed_saturation_<W>``, ``speed_shortfall_<W>``, ``servo_lag_<W>``,
``speed_rate_limit_<W>``, ``steer_saturation_<W>``) are part of
:data:`offline.discrepancy.drive.candidates.DRIVE_CANDIDATES` and fitted only on the wheels the data
implicate (:meth:`DriveRecording.screen`). The effects here are written in this module by code of
their own, not the terms' formulas: a wheel-speed servo with a state of its own that slews toward
its target at a bounded acceleration, the target being the command clipped at a supply-limited
speed (a rate limiter in series with a saturation, where the terms clip the command and ramp the
clipped command tick by tick); and a steering servo that stops at a mechanical end stop reached
through its own slew (where the term clips the command). Budget: 12 s drives; two diagnoses (the
per-wheel terms beside the RL wheel's radius, the base library's best attempt at the RL servo on
main: -20 % at its bound; or beside the IMU tilt, no re-simulation), no recalibration, no empirical
stage; the rest are free scores. 28.8 CPU-s for the file at load 8-9 (31.3 on main at load 9-10,
with three diagnoses; ``tests/bench/results_issue24_time.md``). The full library, 40 s drives and
20 noise-only drives are in ``tests/bench/bench_drive_actuators.py``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from concealed_effects import Effect, record_concealed
from offline.discrepancy.drive.candidates import DRIVE_CANDIDATES
from offline.discrepancy.drive.diagnosis import DriveModel, DriveRecording, diagnose_drives, load_drives
from offline.discrepancy.drive.synthetic import CALIBRATION_SEGMENTS
from offline.discrepancy.significance import normalised
from offline.rover.scenario import load_scenario
from offline.sim.truth import WHEELS
from rtctl.messages import Commands

ROOT = Path(__file__).resolve().parents[1]
SC = load_scenario(ROOT / "offline/scenarios/nominal.toml")
DURATION = 12.0
LOOKALIKES = ("wheel_radius_RL",)
PER_WHEEL = [c for c in DRIVE_CANDIDATES if c.screened]


class SlewingSupplyLimitedServo(Effect):
    """A wheel-speed servo with a state: each command period its rim speed moves toward its target
    by at most ``accel * period``; the target is the command, limited in magnitude to ``v_max``
    (the speed its supply voltage reaches). The recording keeps the commanded speed."""

    def __init__(self, wheel: str = "RL", v_max: float = 0.038, accel: float = 0.25, period: float = 0.2) -> None:
        self.i, self.v_max, self.accel, self.period = WHEELS.index(wheel), v_max, accel, period
        self.v: float | None = None
        self.name = "slewing_supply_limited_servo"
        self.physics = "one wheel-speed servo: bounded acceleration toward a supply-limited speed"

    def actuator_path(self, c: Commands) -> Commands:
        cmd = c.rim_speed[self.i]
        target = cmd if abs(cmd) <= self.v_max else self.v_max * (1.0 if cmd > 0 else -1.0)
        if self.v is None:
            self.v = target
        step = self.accel * self.period
        self.v += min(max(target - self.v, -step), step)
        return replace(c, rim_speed=tuple(self.v if j == self.i else x for j, x in enumerate(c.rim_speed)))


class SteeringEndStop(Effect):
    """A steering servo that meets a mechanical end stop at ``stop`` (rad, either side): it slews at
    ``rate`` toward its command and stops where the stop is (state of its own)."""

    def __init__(self, wheel: str = "FL", stop: float = math.radians(40.0), rate: float = 1.0, period: float = 0.2) -> None:
        self.i, self.stop, self.rate, self.period = WHEELS.index(wheel), stop, rate, period
        self.a: float | None = None
        self.name = "steering_end_stop"
        self.physics = "one steering servo against a mechanical end stop"

    def actuator_path(self, c: Commands) -> Commands:
        cmd = c.steer_angle[self.i]
        self.a = cmd if self.a is None else self.a + min(max(cmd - self.a, -self.rate * self.period), self.rate * self.period)
        self.a = min(max(self.a, -self.stop), self.stop)
        return replace(c, steer_angle=tuple(self.a if j == self.i else x for j, x in enumerate(c.steer_angle)))


def _screen(path: Path) -> dict[str, tuple[bool, str, Any]]:
    model = DriveModel(SC, None)
    obs = DriveRecording.build(load_drives([path]), model, 5)
    pred, _ = model.predict(obs, None)
    scale = obs.dispersion(pred)
    return obs.screen(PER_WHEEL, [], normalised(obs, pred, scale), scale, 0.001, model)


def _diagnose(path: Path, seed: int, base: tuple[str, ...] = LOOKALIKES, screened: bool = True) -> Any:
    lib = [c for c in DRIVE_CANDIDATES if c.key in base or (screened and c.screened)]
    return diagnose_drives([path], SC, candidates=lib, recalibrate=False, empirical=False, seed=seed)


def test_every_per_wheel_term_is_in_the_default_library_and_screened():
    keys = {c.key for c in PER_WHEEL}
    assert keys == {f"{k}_{w}" for k in ("speed_saturation", "speed_shortfall", "servo_lag", "speed_rate_limit",
                                         "steer_saturation") for w in WHEELS}


def test_encoders_screen_in_only_the_wheel_that_misbehaves(tmp_path):
    """The free scores (no re-simulation) admit the speed terms of the slewing servo's wheel and its
    slew-rate limit on top of its cap, at the servo's acceleration within 20 % (0.08 m/s^2 with a
    supply limit of 60 mm/s, so both act; the calibration script without its reverse leg, through
    which a wheel reversing this slowly leaves the plant no equilibrium), the steering cap of the
    end stop's wheel (and no slew there), and nothing on a noise-only drive."""
    eff = SlewingSupplyLimitedServo(v_max=0.06, accel=0.08)
    speed = _screen(record_concealed(tmp_path / "s.mcap", SC, eff, seed=3, duration=DURATION, segments=CALIBRATION_SEGMENTS[:-1]))
    assert {k for k, (ok, *_) in speed.items() if ok} >= {"speed_saturation_RL", "speed_shortfall_RL", "speed_rate_limit_RL"}
    assert all(k.endswith("_RL") and not k.startswith("steer") for k, (ok, *_) in speed.items() if ok)
    accel = speed["speed_rate_limit_RL"][2][0]
    assert abs(accel - eff.accel) <= 0.2 * eff.accel, speed["speed_rate_limit_RL"]
    steer = _screen(record_concealed(tmp_path / "t.mcap", SC, SteeringEndStop(), seed=3, duration=DURATION))
    assert {k for k, (ok, *_) in steer.items() if ok} == {"steer_saturation_FL"}
    noise = _screen(record_concealed(tmp_path / "n.mcap", SC, Effect(), seed=5, duration=DURATION))
    assert not [k for k, (ok, *_) in noise.items() if ok], noise


def test_wheel_speed_saturation_is_named_on_its_wheel_with_its_level(tmp_path):
    """The slewing, supply-limited RL servo of this module is named speed_saturation_RL with its
    limit within 20 %; no other wheel's term is fitted (the screen)."""
    eff = SlewingSupplyLimitedServo()
    v = _diagnose(record_concealed(tmp_path / "sat.mcap", SC, eff, seed=3, duration=DURATION), seed=3)
    fitted = [k for k, ok, _ in v.screening if ok]
    assert fitted and all(k.endswith("_RL") for k in fitted), v.screening
    assert v.status in ("explained", "partly_explained"), v.summary()
    assert v.chosen is not None and v.chosen.keys[0] == "speed_saturation_RL", v.summary()
    cap = v.chosen.values[0] * 1e-3  # mm/s -> m/s
    assert abs(cap - eff.v_max) <= 0.2 * eff.v_max, (cap, eff.v_max)


@pytest.mark.parametrize("seed", [5])
def test_noise_only_drive_yields_no_per_wheel_term(tmp_path, seed, monkeypatch):
    """Nothing screened in, so the diagnosis is the one without the per-wheel terms, draw for draw:
    the screen draws nothing (it takes no generator) and the library the engine fits is the base
    library, candidate for candidate (the first task list the engine hands out is that library's
    fits; one diagnosis, where comparing with a second diagnosis without the per-wheel terms
    doubles the cost)."""
    import offline.discrepancy.engine as engine

    f = record_concealed(tmp_path / "noise.mcap", SC, Effect(), seed=seed, duration=DURATION)
    handed: list[list[Any]] = []
    real = engine.map_tasks

    def spy(fn: Any, items: Any, *a: Any, **k: Any) -> Any:
        handed.append(list(items))
        return real(fn, items, *a, **k)

    monkeypatch.setattr(engine, "map_tasks", spy)
    v = _diagnose(f, seed, base=("imu_tilt",))
    assert len(v.screening) == len(PER_WHEEL) == 20 and not [k for k, ok, _ in v.screening if ok], v.screening
    assert handed[0] == [c for c in DRIVE_CANDIDATES if c.key == "imu_tilt"], handed[0]
    assert not any(k.startswith(("speed_", "steer_saturation")) or k.endswith(tuple(f"lag_{w}" for w in WHEELS))
                   for s in v.scores for k in s.keys)
    assert v.status == "agree", v.summary()

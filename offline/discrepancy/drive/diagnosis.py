"""Discrepancy on rover drive recordings (issue 14), on the same engine as the single-wheel tool.

A recorded drive (MCAP, :mod:`rtctl.recording`) is re-simulated with the recorded commands
and the simulator of the believed parameter files, every recorded channel is compared, and
:func:`offline.discrepancy.engine.diagnose` -- the one engine: candidate library, held-out
significance with a tangent-bootstrap min-P null, "parameters off", indistinguishable sets,
"partly explained", report format -- locates, names and fits the missing physics from the
rover-level library :data:`offline.discrepancy.drive.candidates.DRIVE_CANDIDATES`.

Re-simulation (:class:`DriveModel`)
-----------------------------------
:class:`offline.sim.simulator.RoverSimulator` with the believed truth (plus a candidate's
terms) is started at the steady state of the first commands and stepped once per recorded
tick with the commands recorded at the previous tick (they act until the next tick). The
*heading* is teacher-forced to the recorded one (pose fixes, interpolated to the tick) before
every step: at drive speeds the plant is quasi-static (soil damping time constant of
milliseconds), so the state at a tick depends on the actuator states (driven by the recorded
commands) and on the heading (gravity direction on a slope); forcing the heading keeps an
open-loop heading drift from turning into a slowly growing, time-correlated residual. Each
prediction is then local in time. Candidates whose force depends on where the rover is (a
tether to a fixed anchor) see the recorded pose of the tick being solved, for the same reason.

Observations (:class:`DriveRecording`): rows are time segments
--------------------------------------------------------------
Rows are consecutive segments of ``segment`` ticks (default 5 ticks = 1 s at 5 Hz: more rows give the held-out paired tests more power), located by
the features ``time_s``, ``heading_deg`` (recorded) and ``steer_deg`` (mean commanded steer)
(and ``drive`` with several recordings). Channels
are segment means of the per-tick readings -- ``omega_<W>`` (encoder, rad/s), ``torque_<W>``
(motor torque, N m; absent if the rover does not record it), ``yaw_rate`` (gyro), ``roll``,
``pitch`` (IMU) -- and the pose increments over the segment in the body frame of its start,
``dx_body``, ``dy_body`` (m) and ``dheading`` (rad), from the pose fixes.

Time-series-aware noise (so a long drive does not make noise significant): per drive and
channel, the per-tick noise ``sigma`` is the differencing estimator on the model's tick
residuals (root mean square of the first differences within 4 robust sigmas, over sqrt 2:
slow discrepancies, which are what we look for, do not enter it, nor do jumps at command
steps); the correlation left within segments is an AR(1) with lag-1 coefficient
``phi`` estimated from the within-segment deviations, and the noise of a segment mean is the
AR(1) long-run value ``sigma / sqrt(L) * sqrt((1 + phi) / (1 - phi))`` (``phi`` clipped to
[0, 0.9]). Pose increments carry ``sqrt(2)`` times the fix noise, estimated from the second
differences of the fixes (``1.4826 MAD(d2) / sqrt(6)``); adjacent increments share a fix
(correlation -0.5, which makes the sum statistics of the engine conservative). Folds of the
held-out score are contiguous blocks of time (held-out time segments), never interleaved
rows. On top of this, the engine's per-channel dispersion ``s >= 1`` absorbs any noise
underestimate that affects the whole drive.

Correlated null (:meth:`DriveRecording.null_draw`): the engine's bootstrap of the held-out
improvement draws every channel of every drive as an MA(1) series over its segments, with the
segment-to-segment correlation the data show (:func:`_segment_correlation`, from the differences
of the believed model's residuals, kept only when positive and two standard errors above white
noise): a long drive whose noise wanders from segment to segment does not make noise significant.

Identifiability (``withhold_lookalikes``): explanations that claim other physics and fit the
held-out segments equally, or a term the joint fit cannot tell from its absence, make the verdict
``ambiguous`` -- nothing named, the explanations that fit equally listed, and
:meth:`DriveRecording.identification_advice` says which manoeuvres (point turn, crab, reverse,
from the recorded motion) the drive lacks or that a longer / repeated drive is needed.

Bad input: ticks out of order or repeated, commands missing for a tick, irregular tick
periods and non-finite headings are errors naming the file, the sequence number and the fix;
a non-finite reading is left out of its segment mean (documented fallback), and a segment
with no finite reading of a channel is an error.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.messages import Commands
from rtctl.recording import RecordingError, read_recording

from ...physics.params import ParameterSet
from ...rover.scenario import Scenario
from ...sim.actuators import ActuatorConfig, Actuators
from ...sim.plant import SimulationError
from ...sim.sensors import SensorConfig
from ...sim.simulator import RoverSimulator
from ...sim.truth import WHEELS, Truth
from ..engine import Verdict, diagnose
from ..observations import FEATURE_LABELS, Probe
from ..significance import normalised
from .candidates import (
    DRIVE_CANDIDATES,
    RoverExtension,
    actuator_commands,
    disturbance_from_terms,
    recalibration_candidate,
    rover_terms,
    truth_from_terms,
)
from .wheel_set import channel_unit, library_for, tick_channels

__all__ = ["DriveDataError", "DriveData", "DriveRecording", "DriveModel", "load_drives", "diagnose_drives",
           "accepted_extension", "held_out_drives", "TICK_CHANNELS", "POSE_CHANNELS", "DRIVE_ALPHA",
           "DRIVE_ALPHA_AFTER"]

DRIVE_ALPHA = 0.001
"""Family-wise false-alarm level of each test of a drive diagnosis (the candidate test, the region
test over the 14 channels, the lack-of-fit test): 0.001, where the single-wheel tool uses 0.01.
Chosen from the requirement, not from a seed: a team replays every drive, and the issue asks for
no false alarm over a set of negative-control drives. With two tests that can each raise an alarm
on noise (a candidate, a region) at 0.01, 20 noise-only drives give at least one false alarm with
probability 1 - 0.98^20 = 33 % even for exact tests; at 0.001, 4 %. The Monte-Carlo sizes follow
(3 / level draws). What it costs in power is measured on the benchmark's effects
(``tests/bench/results_drive_discrepancy.md``). The checks of what an accepted explanation
leaves keep :data:`DRIVE_ALPHA_AFTER`."""

DRIVE_ALPHA_AFTER = 0.01
"""Level of the checks after an explanation is accepted (regions and lack of fit of what it
leaves): 0.01. Their error on the wrong side is the other one: missing a remainder calls a
partial explanation 'explained' (an effect outside the library absorbed by look-alike terms),
so they keep the higher level; a false positive there only makes the verdict 'partly
explained' with the named physics still reported. On the 24 s hub-drag test drive, RR radius +
tether absorb 75 % of the excess and the yaw-rate misfit they leave has p = 3.3e-4: 'partly
explained' at 0.01 / 14, 'explained' at 0.001 / 14."""

SCREEN_FRACTION = 0.5
"""A screened per-wheel term is fitted when its free score on its own wheel's encoder reaches this
fraction of ``chi2_1(1 - alpha)`` (:meth:`DriveRecording.screen`): a margin of two on the least a
one-parameter term must gain to pass the library's test."""
SCREEN_FAMILY_FRACTION = 0.25
"""A screened term whose free score is below this fraction of its family's best is not fitted
(:meth:`DriveRecording.screen`: a look-alike must reach 75 % of the best's improvement)."""
SCREEN_GRID = 41
"""Parameter values of a screened term's free score (evenly over its box, plus its starts)."""

TICK_CHANNELS = (*(f"omega_{w}" for w in WHEELS), *(f"torque_{w}" for w in WHEELS), "yaw_rate", "roll", "pitch")
"""Per-tick readings averaged over a segment."""
POSE_CHANNELS = ("dx_body", "dy_body", "dheading")
"""Pose increments over a segment (body frame of its start)."""
_UNITS = {**{f"omega_{w}": ("rad/s", 1.0) for w in WHEELS}, **{f"torque_{w}": ("N m", 1.0) for w in WHEELS},
          "yaw_rate": ("deg/s", 180 / math.pi), "roll": ("deg", 180 / math.pi), "pitch": ("deg", 180 / math.pi),
          "dx_body": ("mm", 1e3), "dy_body": ("mm", 1e3), "dheading": ("deg", 180 / math.pi)}
FEATURE_LABELS.update({"time_s": "time (s)", "heading_deg": "heading (deg)", "steer_deg": "mean steer (deg)"})


class DriveDataError(ValueError):
    """A drive recording cannot be used; the message names the file, the tick and the fix."""


@dataclass(frozen=True)
class DriveData:
    """One recorded drive, tick by tick (SI; wheel order :attr:`wheels`).

    Attributes
    ----------
    source : str
        File name.
    t : ndarray (n,)
        Tick times, s (uniform, period ``period``).
    rim_cmd, steer_cmd : ndarray (n, 4)
        Commands recorded at each tick (they act until the next tick).
    readings : dict
        :data:`TICK_CHANNELS` (those recorded), (n,) each; NaN where not finite.
    pose : ndarray (n, 3)
        Pose (x, y, heading) at the ticks, interpolated from the fixes (heading unwrapped).
    pose_sigma : tuple of 2 float
        Fix noise (position m, heading rad) from the fixes' second differences.
    heading_source : str
        ``pose fixes`` or ``gyro integration`` (no pose source recorded).
    steer_reading : ndarray (n, 4) or None
        The steering encoders at the ticks, rad (NaN where not finite). Not a channel of the
        observations (the model takes the commanded steering); it screens the steering-saturation
        terms (:meth:`DriveRecording.screen`).
    """

    source: str
    t: NDArray[np.float64]
    period: float
    rim_cmd: NDArray[np.float64]
    steer_cmd: NDArray[np.float64]
    readings: dict[str, NDArray[np.float64]]
    pose: NDArray[np.float64]
    pose_sigma: tuple[float, float]
    heading_source: str
    steer_reading: NDArray[np.float64] | None = None

    @property
    def wheels(self) -> tuple[str, ...]:
        """The recording's wheel set, the order of every per-wheel column (issue 23): the wheels of
        its ``omega_<W>`` readings, which :meth:`from_file` takes from
        :attr:`rtctl.recording.Recording.wheels` in its order (the mini rover's FR, FL, RR, RL for a
        recording that names none)."""
        return tuple(k[len("omega_"):] for k in self.readings if k.startswith("omega_"))

    @classmethod
    def from_file(cls, path: str | Path, gyro_bias: float = 0.0) -> "DriveData":
        """Read and check an MCAP drive recording (:func:`rtctl.recording.read_recording`)."""
        p = Path(path)
        try:
            rec = read_recording(p)
        except RecordingError as exc:
            raise DriveDataError(str(exc)) from None
        name = p.name
        ms = rec.measurements
        if len(ms) < 12:
            raise DriveDataError(f"{name}: {len(ms)} measurement ticks; a drive needs at least 12 (two segments)")
        seq = np.array([m.seq for m in ms])
        t = np.array([m.t for m in ms], dtype=float)
        bad = np.flatnonzero(np.diff(seq) <= 0)
        if bad.size:
            raise DriveDataError(f"{name}: measurement seq {seq[bad[0] + 1]} after {seq[bad[0]]} (repeated or out of "
                                 "order); drop the repeated ticks or sort the recording by seq")
        if not np.all(np.isfinite(t)):
            raise DriveDataError(f"{name}: measurement seq {seq[np.flatnonzero(~np.isfinite(t))[0]]} has no finite time stamp")
        dt = np.diff(t)
        period = float(np.median(dt))
        irregular = np.flatnonzero(np.abs(dt - period) > 1e-3 * period + 1e-9)
        if irregular.size:
            i = irregular[0]
            raise DriveDataError(f"{name}: tick period {dt[i]:.4g} s between seq {seq[i]} and {seq[i + 1]}, the drive's "
                                 f"period is {period:.4g} s; the re-simulation needs a fixed period: cut the drive at the gap")
        cmds = {c.seq: c for c in rec.commands}
        missing = [int(s) for s in seq if int(s) not in cmds]
        if missing:
            raise DriveDataError(f"{name}: no commands recorded for measurement seq {missing[0]} ({len(missing)} ticks "
                                 "without commands); a drive is re-simulated from its recorded commands")
        rim = np.array([cmds[int(s)].rim_speed for s in seq], dtype=float)
        steer = np.array([cmds[int(s)].steer_angle for s in seq], dtype=float)
        if not (np.all(np.isfinite(rim)) and np.all(np.isfinite(steer))):
            i = int(np.flatnonzero(~np.all(np.isfinite(np.hstack([rim, steer])), axis=1))[0])
            raise DriveDataError(f"{name}: commands of seq {seq[i]} are not finite (commands are always finite)")
        rd: dict[str, NDArray[np.float64]] = {}
        wheels = tuple(getattr(rec, "wheels", WHEELS))
        ws = np.array([m.wheel_speed for m in ms], dtype=float)
        for i, w in enumerate(wheels):
            rd[f"omega_{w}"] = ws[:, i]
        if all(m.motor_torque is not None for m in ms):
            tq = np.array([m.motor_torque for m in ms], dtype=float)
            for i, w in enumerate(wheels):
                rd[f"torque_{w}"] = tq[:, i]
        rd["yaw_rate"] = np.array([m.yaw_rate for m in ms], dtype=float)
        rd["roll"] = np.array([m.roll for m in ms], dtype=float)
        rd["pitch"] = np.array([m.pitch for m in ms], dtype=float)
        rd = {k: np.where(np.isfinite(v), v, np.nan) for k, v in rd.items()}
        fixes = sorted({(m.pose.t, m.pose.x, m.pose.y, m.pose.heading) for m in ms if m.pose is not None})
        fx = np.array([f for f in fixes if all(math.isfinite(v) for v in f)], dtype=float).reshape(-1, 4)
        if len(fx) >= max(4, len(ms) // 4):
            hd = np.unwrap(fx[:, 3])
            pose = np.stack([np.interp(t, fx[:, 0], fx[:, 1]), np.interp(t, fx[:, 0], fx[:, 2]),
                             np.interp(t, fx[:, 0], hd)], axis=1)
            d2 = np.diff(fx[:, 1:3], n=2, axis=0)
            sxy = 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0)
            sh = 1.4826 * float(np.median(np.abs(np.diff(hd, n=2)))) / math.sqrt(6.0)
            src = f"pose fixes ({len(fx)})"
        else:
            yaw = np.nan_to_num(rd["yaw_rate"] - gyro_bias)
            hd = np.concatenate([[0.0], np.cumsum(0.5 * (yaw[1:] + yaw[:-1]) * dt)])
            pose = np.stack([np.full_like(t, np.nan), np.full_like(t, np.nan), hd], axis=1)
            sxy = sh = math.nan
            src = "gyro integration (fewer than a quarter of the ticks carry a pose fix; no pose channels)"
        enc = np.array([m.steer_angle for m in ms], dtype=float)
        enc = np.where(np.isfinite(enc), enc, np.nan)
        return cls(name, t - t[0], period, rim, steer, rd, pose, (max(sxy, 1e-5), max(sh, 1e-5)), src, enc)


def _step(sim: RoverSimulator, dt: float, depth: int = 0, halvings: int = 0) -> None:
    """One plant step of ``dt``; where Newton finds no equilibrium, the step is split in halves (at
    most ``halvings`` times, down to ``dt / 2**halvings``) from the same state.

    The simulator's own step already retries a failed step (:meth:`RoverSimulator.step`: the exact
    rocker Jacobian, then 2, 4, 8 and 16 sub-steps continued from one another with the servos
    moving linearly over them, then from rest), so :attr:`DriveModel.halvings` is 0: the halving
    (three, before the simulator sub-stepped) repeated every one of those retries on each half;
    measured, it rescued none of the ticks whose step failed in the two diagnoses of
    ``tests/bench/results_issue24_time.md`` (2026-11-27), and it made each lost tick cost four
    times the simulator's retries."""
    keep = sim.act.steer.copy(), sim.act.omega_servo.copy(), sim.z.copy()
    sim.dt = dt
    try:
        sim.step()
    except SimulationError:
        if depth >= halvings:
            raise
        sim.act.steer, sim.act.omega_servo, sim.z = keep
        _step(sim, dt / 2, depth + 1, halvings)
        _step(sim, dt / 2, depth + 1, halvings)


def _sum_hooks(a: Callable[[float, Any], Any], b: Callable[[float, Any], Any]) -> Callable[[float, Any], Any]:
    """Two disturbance hooks at once (forces, moments and torques add)."""
    from ...sim.simulator import DisturbanceForces

    def hook(t: float, s: Any) -> Any:
        f, g = a(t, s), b(t, s)
        n = max(len(f.wheel_torque), len(g.wheel_torque))  # a body-only hook's zeros fit any wheel count
        v = f.vector(n) + g.vector(n)
        return DisturbanceForces(body_force=(v[0], v[1]), body_moment_z=v[2],
                                 wheel_force=tuple(zip(v[3:3 + n], v[3 + n:3 + 2 * n])), wheel_torque=tuple(v[3 + 2 * n:]))

    return hook


def _recorded_pose(d: DriveData) -> Callable[[float], tuple[float, float, float]] | None:
    """The recorded pose at time t in the frame of the drive's start pose (for hooks that depend on
    where the rover is, :class:`offline.discrepancy.drive.candidates.AnchoredTether`); None without pose
    fixes (the hook then takes the simulator's dead-reckoned state)."""
    if not np.all(np.isfinite(d.pose[:, :2])):
        return None
    x0, y0, h0 = d.pose[0]
    c, s = math.cos(h0), math.sin(h0)
    X = c * (d.pose[:, 0] - x0) + s * (d.pose[:, 1] - y0)
    Y = -s * (d.pose[:, 0] - x0) + c * (d.pose[:, 1] - y0)
    H = d.pose[:, 2] - h0
    t = d.t

    def at(tt: float) -> tuple[float, float, float]:
        return float(np.interp(tt, t, X)), float(np.interp(tt, t, Y)), float(np.interp(tt, t, H))

    return at


def load_drives(paths: Sequence[str | Path], gyro_bias: float = 0.0) -> list[DriveData]:
    """Read recordings: files, or folders (every ``*.mcap`` inside, sorted by name)."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(p.glob("*.mcap"))
            if not found:
                raise DriveDataError(f"{p}: folder holds no .mcap recording")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise DriveDataError(f"{p}: no such recording or folder")
    return [DriveData.from_file(f, gyro_bias) for f in files]


def _difference_sigma(r: NDArray[np.float64]) -> float:
    """White-noise level of a series from its first differences: a robust start
    (``1.4826 MAD / sqrt 2``), then the root mean square of the differences within 4 robust
    sigmas (jumps at command steps left out; the 4-sigma clip loses 0.1 % of Gaussian variance).
    The clipped mean square has about 2.7 times the efficiency of the MAD alone, which matters on
    the ~100-tick drives of the tests: a 15 % low noise level makes a 3-sigma chance offset look
    like 3.5 sigma."""
    dd = np.diff(r)
    if dd.size < 3:
        return 0.0
    s0 = 1.4826 * float(np.median(np.abs(dd - np.median(dd))))
    if s0 == 0.0:
        return 0.0
    keep = np.abs(dd - np.median(dd)) <= 4.0 * s0
    return float(np.sqrt(np.mean(dd[keep] ** 2) / 2.0))


@dataclass(frozen=True)
class _Segments:
    """Segment layout of one drive: ``(start_tick, end_tick)`` with ticks ``start+1 .. end`` averaged."""

    bounds: NDArray[np.int_]

    @classmethod
    def of(cls, n: int, length: int) -> "_Segments":
        m = (n - 1) // length
        s = np.arange(m) * length
        return cls(np.stack([s, s + length], axis=1))


def _rows_from_ticks(d: DriveData, seg: _Segments, ticks: Mapping[str, NDArray[np.float64]],
                     body: NDArray[np.float64] | None, channels: Sequence[str]) -> NDArray[np.float64]:
    """Segment rows (n_seg x channels) from tick channels and, for the pose channels, either the
    recorded pose (``body`` None) or the predicted body velocities ``body`` (n, 3: u, v, r)."""
    out = np.empty((len(seg.bounds), len(channels)))
    m = len(seg.bounds)
    length = int(seg.bounds[0, 1] - seg.bounds[0, 0]) if m else 0
    blocks = (body is not None and m > 0 and bool(np.all(seg.bounds[:, 0] == np.arange(m) * length))
              and bool(np.all(seg.bounds[:, 1] == seg.bounds[:, 0] + length)))
    if blocks:
        # a prediction (every call of the engine): the segments are consecutive blocks of
        # ``length`` ticks, so each channel's segment means are one row-wise sum over an (m,
        # length) view -- the same sum and division as np.nanmean of each finite segment, bit
        # for bit; a segment with a lost tick is lost
        for c, ch in enumerate(channels):
            if ch not in POSE_CHANNELS:
                blk = ticks[ch][1:1 + m * length].reshape(m, length)
                out[:, c] = np.where(np.isfinite(blk).all(axis=1), blk.sum(axis=1) / length, np.nan)
    for j, (a, b) in enumerate(seg.bounds):
        for c, ch in enumerate(channels):
            if ch in POSE_CHANNELS or blocks:
                continue
            v = ticks[ch][a + 1:b + 1]
            if body is not None and not np.all(np.isfinite(v)):
                out[j, c] = np.nan  # a predicted segment with a lost tick is lost, never averaged over the gap
            else:
                out[j, c] = float(np.nanmean(v)) if np.isfinite(v).any() else np.nan
        if any(ch in POSE_CHANNELS for ch in channels):
            if body is None:
                x0, y0, h0 = d.pose[a]
                x1, y1, h1 = d.pose[b]
                c0, s0 = math.cos(h0), math.sin(h0)
                inc = {"dx_body": c0 * (x1 - x0) + s0 * (y1 - y0), "dy_body": -s0 * (x1 - x0) + c0 * (y1 - y0),
                       "dheading": h1 - h0}
            else:
                u, v, r = body[a + 1:b + 1].T
                psi = np.cumsum(r) * d.period
                hm = psi - 0.5 * r * d.period
                inc = {"dx_body": float(np.sum(d.period * (u * np.cos(hm) - v * np.sin(hm)))),
                       "dy_body": float(np.sum(d.period * (u * np.sin(hm) + v * np.cos(hm)))), "dheading": float(psi[-1])}
            for c, ch in enumerate(channels):
                if ch in POSE_CHANNELS:
                    out[j, c] = inc[ch]
    return out


def _segment_correlation(series: Sequence[NDArray[np.float64]]) -> float:
    """Lag-1 correlation of a channel's segment residuals, from their first differences so a slow
    discrepancy (what the tool looks for) does not enter: for an MA(1) series with lag-1
    correlation rho, the differences have lag-1 correlation ``r = (2 rho - 1) / (2 - 2 rho)``,
    so ``rho = (1 + 2 r) / (2 + 2 r)`` (white: r = -1/2, rho = 0). Pooled over the drives;
    differences beyond 4 robust sigmas (steps of the discrepancy itself) are set to zero.
    Only a positive correlation shown by the data is kept: ``r`` must exceed -1/2 by two of its
    standard errors (Bartlett, ``sqrt(0.5 / m)`` for m differences), so a short drive keeps
    independent draws and a long one picks up a real correlation; a negative one (adjacent pose
    increments share a fix: -1/2) is left at 0, which keeps the test conservative. Clipped to
    [0, 0.49] (MA(1) range); 0 with fewer than 8 differences."""
    num = den = 0.0
    count = 0
    for z in series:
        dz = np.diff(z[np.isfinite(z)])
        if dz.size < 3:
            continue
        dz = dz - np.median(dz)
        s0 = 1.4826 * float(np.median(np.abs(dz)))
        if s0 == 0.0:
            continue
        # a step of the discrepancy (a manoeuvre change) is one outlying difference: it would pull
        # r from -1/2 towards 0 (rho towards 1/2), so differences beyond 4 robust sigmas are left out
        dz = np.where(np.abs(dz) <= 4.0 * s0, dz, 0.0)
        num += float(dz[1:] @ dz[:-1])
        den += float(dz @ dz)
        count += int(np.count_nonzero(dz))
    if count < 8 or den <= 0.0:
        return 0.0
    r = float(np.clip(num / den, -0.999, 0.999))
    if r < -0.5 + 2.0 * math.sqrt(0.5 / count):  # not above white noise by 2 standard errors (Bartlett)
        return 0.0
    return float(np.clip((1.0 + 2.0 * r) / (2.0 + 2.0 * r), 0.0, 0.49))


@dataclass(frozen=True)
class DriveRecording:
    """Drive recordings as engine observations (:class:`offline.discrepancy.observations.Observations`).

    Rows are time segments of every drive (module notes); ``drive``/``segment`` say which.
    Build with :meth:`build` (the noise comes from the model's tick residuals).
    """

    drives: tuple[DriveData, ...]
    segments: tuple[_Segments, ...]
    drive: NDArray[np.int_]
    segment: NDArray[np.int_]
    channels: tuple[str, ...]
    measured: dict[str, NDArray[np.float64]]
    noise: dict[str, NDArray[np.float64]]
    features: dict[str, NDArray[np.float64]]
    noise_source: str
    source: str
    heading_offset: float = 0.0
    units: Mapping[str, str] = field(default_factory=dict)
    scale_out: Mapping[str, float] = field(default_factory=dict)
    segment_corr: Mapping[str, float] = field(default_factory=dict)
    family_alpha: float = DRIVE_ALPHA

    def __len__(self) -> int:
        return int(self.drive.size)

    @classmethod
    def build(cls, drives: Sequence[DriveData], model: "DriveModel", segment: int = 10) -> "DriveRecording":
        """Segment the drives, re-simulate them with the model as given, estimate the noise."""
        if segment < 2:
            raise DriveDataError(f"segment = {segment} ticks; at least 2 are needed for the noise estimate")
        drives = tuple(drives)
        for d in drives:
            if d.wheels != model.wheels:
                raise DriveDataError(f"{d.source}: the recording's wheels are {', '.join(d.wheels)}; the believed scenario "
                                     f"{model.scenario.name}'s rover has {', '.join(model.wheels)}: diagnose it with the "
                                     "scenario of the rover that drove it")
        have = set.intersection(*(set(d.readings) for d in drives))
        chans = [c for c in tick_channels(model.wheels) if c in have]
        if all(math.isfinite(d.pose[0, 0]) for d in drives):
            chans += list(POSE_CHANNELS)
        segs = tuple(_Segments.of(len(d.t), segment) for d in drives)
        for d, s in zip(drives, segs):
            if len(s.bounds) < 2:
                raise DriveDataError(f"{d.source}: {len(d.t)} ticks make {len(s.bounds)} segment(s) of {segment} ticks; "
                                     "record a longer drive or use shorter segments")
        meas, noise, feats, zs = [], [], [], []
        phis = []
        for k, (d, s) in enumerate(zip(drives, segs)):
            m = _rows_from_ticks(d, s, d.readings, None, chans)
            bad = np.argwhere(~np.isfinite(m))
            if bad.size:
                j, c = bad[0]
                raise DriveDataError(f"{d.source}: no finite {chans[c]} reading in segment {j} (t = {d.t[s.bounds[j, 0]]:.1f}-"
                                     f"{d.t[s.bounds[j, 1]]:.1f} s); drop the channel's sensor or cut the drive")
            ticks, body, ok = model.simulate(d, None, 0.0)
            if not ok:
                raise DriveDataError(f"{d.source}: the believed simulator cannot re-simulate this drive (no equilibrium); "
                                     "check the scenario and parameter files are for this rover")
            nz = np.empty_like(m)
            for c, ch in enumerate(chans):
                if ch in POSE_CHANNELS:
                    nz[:, c] = math.sqrt(2.0) * (d.pose_sigma[1] if ch == "dheading" else d.pose_sigma[0])
                    continue
                r = d.readings[ch] - ticks[ch]
                r = r[1:]
                sig = _difference_sigma(r[np.isfinite(r)])
                dev = np.concatenate([r[a:b] - np.nanmean(r[a:b]) for a, b in s.bounds])
                dev = np.nan_to_num(dev)
                phi = float(np.clip((dev[1:] * dev[:-1]).sum() / max((dev**2).sum(), 1e-300), 0.0, 0.9))
                phis.append(phi)
                floor = 1e-9 * max(1.0, float(np.nanmax(np.abs(d.readings[ch]))))
                nz[:, c] = max(sig, floor) / math.sqrt(segment) * math.sqrt((1 + phi) / (1 - phi))
            meas.append(m)
            noise.append(nz)
            zs.append((m - _rows_from_ticks(d, s, ticks, body, chans)) / nz)
            mid = s.bounds.mean(axis=1).astype(int)
            hd = d.pose[:, 2]
            feats.append({"time_s": d.t[mid], "heading_deg": np.degrees([hd[a:b + 1].mean() for a, b in s.bounds]),
                          "steer_deg": np.degrees([d.steer_cmd[a:b].mean() for a, b in s.bounds])})
        M, N = np.vstack(meas), np.vstack(noise)
        drive = np.concatenate([np.full(len(s.bounds), k) for k, s in enumerate(segs)])
        segi = np.concatenate([np.arange(len(s.bounds)) for s in segs])
        features = {f: np.concatenate([x[f] for x in feats]) for f in feats[0]}
        if len(drives) > 1:
            features["drive"] = drive.astype(float)
        corr = {c: _segment_correlation([z[:, i] for z in zs]) for i, c in enumerate(chans)}
        src = (f"per tick: differencing estimator on the model's tick residuals; segment means of {segment} ticks with "
               f"the AR(1) long-run variance (lag-1 phi up to {max(phis, default=0):.2f}); pose increments sqrt(2) x the "
               "fix noise from second differences of the fixes; segment-to-segment correlation (MA(1), from the "
               "differences of the residuals) " + ", ".join(f"{c} {r:+.2f}" for c, r in corr.items() if abs(r) >= 0.1))
        return cls(drives, segs, drive, segi, tuple(chans), {c: M[:, i] for i, c in enumerate(chans)},
                   {c: N[:, i] for i, c in enumerate(chans)}, features, src,
                   ", ".join(d.source for d in drives),
                   units={c: channel_unit(c, _UNITS)[0] for c in chans}, scale_out={c: channel_unit(c, _UNITS)[1] for c in chans},
                   segment_corr=corr)

    def null_draw(self, rng: np.random.Generator, n: int, n_boot: int) -> NDArray[np.float64]:
        """Noise draws for the engine's significance test (:func:`offline.discrepancy.significance.tangent_null`):
        rows x channels flattened row-major, one column per draw, each channel of each drive a
        unit-variance MA(1) series over its segments with the lag-1 correlation
        :attr:`segment_corr` (``e_j = (w_j + theta w_{j-1}) / sqrt(1 + theta^2)``,
        ``theta / (1 + theta^2) = rho``). Independent draws would treat adjacent segments as
        independent; a correlation between them (pose increments share a fix, slow sensor
        wander) would then make noise significant on a long drive."""
        nc = len(self.channels)
        if n != len(self) * nc:
            raise ValueError(f"null_draw: {n} values asked, the observations have {len(self)} rows x {nc} channels")
        out = np.empty((len(self), nc, n_boot))
        for k in np.unique(self.drive):
            rows = np.flatnonzero(self.drive == k)
            rows = rows[np.argsort(self.segment[rows])]
            for c, ch in enumerate(self.channels):
                out[rows, c] = self._ma1(rng, ch, rows.size, n_boot)
        return out.reshape(n, n_boot)

    def channel_null_draw(self, rng: np.random.Generator, channel: str, n_draws: int) -> NDArray[np.float64]:
        """``(n_draws, rows)`` noise draws of one channel for the engine's region test
        (:func:`offline.discrepancy.significance.locate`): per drive the same unit-variance MA(1) series
        over the segments as :meth:`null_draw`, so a box of adjacent segments is judged against
        correlated noise, not independent rows."""
        if channel not in self.channels:
            raise ValueError(f"channel_null_draw: unknown channel {channel!r}; channels are {list(self.channels)}")
        out = np.empty((n_draws, len(self)))
        for k in np.unique(self.drive):
            rows = np.flatnonzero(self.drive == k)
            rows = rows[np.argsort(self.segment[rows])]
            out[:, rows] = self._ma1(rng, channel, rows.size, n_draws).T
        return out

    def _ma1(self, rng: np.random.Generator, channel: str, n_rows: int, n_draws: int) -> NDArray[np.float64]:
        """``(n_rows, n_draws)`` unit-variance MA(1) series with lag-1 correlation ``segment_corr[channel]``."""
        rho = float(np.clip(self.segment_corr.get(channel, 0.0), -0.49, 0.49))
        theta = 0.0 if rho == 0.0 else (1.0 - math.sqrt(1.0 - 4.0 * rho * rho)) / (2.0 * rho)
        w = rng.standard_normal((n_rows + 1, n_draws))
        return (w[1:] + theta * w[:-1]) / math.sqrt(1.0 + theta * theta)

    lack_of_fit_floor: float = 3.0
    """With nothing in the library significant and no region located, a channel whose believed-model
    residuals exceed the noise (chi-square at alpha / channels) by more than this factor in
    chi2 / rows makes the verdict 'unexplained' instead of 'agree'. The segment noise estimate
    can be off by up to about a factor 2 in variance: in 20 negative-control drives the test
    alone fired once, at chi2 / rows 1.95 (``bench_drive_discrepancy.py lack_of_fit``); a
    3 mm terrain undulation gives 3.1-420. 3 keeps that margin on both sides."""

    name_needs_excess: bool = True
    """A significant explanation is named only when the believed model's residuals exceed the noise
    (chi-square in noise units over every channel above the number of values,
    :func:`offline.discrepancy.engine.withhold_without_excess`); otherwise nothing is named. The
    candidate test's null draws noise around fixed commands, but in a closed-loop drive the
    commands react to the noise: on README's ``offnominal drive`` with no effect (seed 33) an FL
    radius of +0.53 % passed at p = 3.3e-4 with no excess over noise, and made a held-out drive
    worse. Every named effect of the drive benchmark has a residual chi-square above the number
    of values (``tests/bench/results_drive_discrepancy.md``)."""

    withhold_lookalikes: bool = True
    """Look-alikes that fit equally make the verdict 'ambiguous' (nothing named): a drive can be
    repeated with a manoeuvre that separates them (:meth:`identification_advice`)."""

    def manoeuvres(self) -> dict[str, float]:
        """Seconds of each manoeuvre the rover made, from the recorded motion:
        ``turn`` (yaw rate beyond 3 deg/s), ``crab`` (travel direction more than 10 deg off the
        heading, forward), ``reverse`` (travelling backward), ``straight`` (none of these), each
        judged over 2 s windows (a 3 mm fix noise on a 6 mm step would make every tick a crab).

        With pose fixes at every segment, all four come from the fixes. Without them (no pose
        source, or fixes too sparse: :class:`DriveData` then integrates the gyro), the turn comes
        from the gyro's yaw rate -- the rover's measured motion -- and only crab and reverse from
        the commands: the crab when the median commanded steer is beyond 10 deg (all wheels at one
        angle), the reverse when every rim speed is negative. The commands' spread is no turn: a
        declared stuck wheel's command and a controller's compensating steer are none (README's
        rr_steer_stuck_50 under rtctl spreads them by over 50 deg on a straight drive)."""
        out = {"straight": 0.0, "turn": 0.0, "crab": 0.0, "reverse": 0.0}
        for d in self.drives:
            w = max(1, int(round(2.0 / d.period)))  # 2 s windows: pose-fix noise averages out
            n = (len(d.t) - 1) // w
            if n == 0:
                continue
            if np.all(np.isfinite(d.pose[:, :2])):
                dp = d.pose[w:n * w + 1:w] - d.pose[0:n * w:w]
                h = d.pose[0:n * w:w, 2] + 0.5 * dp[:, 2]
                u = np.cos(h) * dp[:, 0] + np.sin(h) * dp[:, 1]
                v = -np.sin(h) * dp[:, 0] + np.cos(h) * dp[:, 1]
                moving = np.hypot(u, v) > 2e-3 * w * d.period
                turn = np.abs(dp[:, 2]) / (w * d.period) > math.radians(3.0)
                rev = moving & (u < 0) & ~turn
                crab = moving & ~turn & ~rev & (np.abs(np.arctan2(v, u)) > math.radians(10.0))
            else:
                st, rim = d.steer_cmd[0:n * w:w], d.rim_cmd[0:n * w:w]
                yaw = d.readings["yaw_rate"][1:n * w + 1].reshape(n, w)
                ok: NDArray[np.bool_] = np.asarray(np.isfinite(yaw).any(axis=1))
                rate = np.abs(np.nanmean(np.where(ok[:, None], yaw, 0.0), axis=1))
                turn = ok & (rate > math.radians(3.0))
                rev = np.all(rim < 0.0, axis=1) & ~turn
                crab = ~turn & ~rev & (np.abs(np.median(st, axis=1)) > math.radians(10.0))
            span = w * d.period
            out["turn"] += span * float(turn.sum())
            out["crab"] += span * float(crab.sum())
            out["reverse"] += span * float(rev.sum())
            out["straight"] += span * float((~turn & ~crab & ~rev).sum())
        return out

    def identification_advice(self) -> str:
        """What to drive so that explanations which fit this recording equally can be told apart:
        the calibration manoeuvres the recording lacks (a straight closed-loop drive cannot separate
        a tether from a softer soil or a worn wheel, nor one front wheel's steering offset from the
        other's), or a longer drive when it already has them all."""
        have = self.manoeuvres()
        wanted = {"turn": "a point turn or Ackermann turns both ways",
                  "crab": ("crabs both ways at a large angle (all wheels at one angle, about 60 deg: it separates "
                           "one front wheel's steering offset from the other's)"),
                  "reverse": "a reverse leg"}
        need = [text for m, text in wanted.items() if have[m] < 1.0]
        rec = ", ".join(f"{k} {v:.0f} s" for k, v in have.items())
        if need:
            return (f"Drive a calibration manoeuvre to separate or determine them: this recording has {rec}; add "
                    f"{', '.join(need)} (offline.discrepancy.drive.synthetic.calibration_drive is such a script)")
        return (f"This recording already has every calibration manoeuvre ({rec}) but too few segments to separate or "
                "determine them: repeat the calibration drive (held-out drives) or drive it longer")

    @property
    def locate_alpha(self) -> float:
        """Per-channel level of the engine's region test: :attr:`family_alpha` / channels
        (Bonferroni over the 14 channels of a drive, so the drive's family-wise false-alarm level
        of the region test is :attr:`family_alpha`, :data:`DRIVE_ALPHA` unless the diagnosis sets another)."""
        return self.family_alpha / len(self.channels)

    @property
    def locate_perm(self) -> int:
        """Monte-Carlo draws of the region test: 3 / locate_alpha (the smallest attainable p-value
        must lie below the level)."""
        return int(math.ceil(3.0 / self.locate_alpha))

    def dispersion(self, pred: Mapping[str, NDArray[np.float64]]) -> dict[str, float]:
        """Per-channel dispersion ``s >= 1`` for the engine, from the *differences* of consecutive
        segments' normalised residuals: ``max(1, 1.4826 MAD(diff z) / sqrt 2)`` within each drive.

        The engine's default (the MAD of the residuals themselves) absorbs an effect that varies
        over the drive -- a cross slope's pitch signal turns with the heading -- into the noise
        (s = 22 for the pitch of a 3.5 deg cross slope), which then down-weights exactly the
        channel that carries the effect. Differences keep slow structure out and still catch a
        model that misses from segment to segment by more than the noise.
        """
        out = {}
        for ch in self.channels:
            z = (self.measured[ch] - pred[ch]) / self.noise[ch]
            dz = []
            for k in np.unique(self.drive):
                rows = np.flatnonzero(self.drive == k)
                zz = z[rows[np.argsort(self.segment[rows])]]
                dz.append(np.diff(zz[np.isfinite(zz)]))
            d = np.concatenate(dz) if dz else np.zeros(0)
            out[ch] = max(1.0, 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)) if d.size > 2 else 1.0
        return out

    def subset(self, idx: NDArray[np.int_]) -> "DriveRecording":
        """Rows ``idx`` only (the drives stay whole: a prediction re-simulates the whole drive)."""
        idx = np.asarray(idx)
        return replace(self, drive=self.drive[idx], segment=self.segment[idx],
                       measured={k: v[idx] for k, v in self.measured.items()},
                       noise={k: v[idx] for k, v in self.noise.items()},
                       features={k: v[idx] for k, v in self.features.items()})

    def with_measured(self, measured: Mapping[str, NDArray[np.float64]]) -> "DriveRecording":
        """Same segments, other measurements (for synthetic studies)."""
        return replace(self, measured={k: np.asarray(v, dtype=float).copy() for k, v in measured.items()})

    def screen(self, candidates: Sequence[Any], regions: Sequence[Any], z0: NDArray[np.float64],
               scale: Mapping[str, float], alpha: float, model: "DriveModel"
               ) -> dict[str, tuple[bool, str, tuple[float, ...] | None]]:
        """Which screened candidates (the per-wheel actuator terms) are fitted: ``{key: (fitted, why,
        start)}``, ``start`` the parameter (reported units) of the best free score (None without one):
        the engine fits the term from it and its declared start instead of its declared starts (the
        free score's grid is a search over the whole box, the declared starts three points of it).

        A term of wheel ``W`` (its family ``speed_W`` or ``steer_W``) acts on what that wheel's
        servo does, which that wheel's own encoder measures directly. It is fitted when its **free
        score** reaches ``SCREEN_FRACTION`` (one half) of ``chi2_1(1 - alpha)``, the least a
        one-parameter term must gain to pass the library's test: the largest improvement, over a
        grid of its parameter (:data:`SCREEN_GRID` points over its box, its start and its starts),
        that the term's change of the commands alone makes on the wheel's own encoder, with no
        re-simulation --

           - speed terms: on the ``omega_W`` rows in the units of the held-out test (noise x
             dispersion), the predicted wheel speed moved by the change of that wheel's rim-speed
             command over the shearing radius (the wheel follows its servo's reference: the
             believed lag, 0.05 s, is a quarter of a tick). A torque-limited wheel does not follow,
             so the score is optimistic there, the safe side of a screen;
           - the slew-rate limit (family ``slew_W``): the same score of what the ramp adds on top
             of the wheel's best speed term at its best value when that term passes the screen
             (a rate limiter in series with a cap: the encoder minus the capped prediction
             against the ramp's change of the capped command), on its own otherwise;
           - the steering cap: on every tick of the steering encoder, with its white noise from
             the first differences: the encoder minus the believed servo angle (the recorded
             commands through the simulator's own steering servo, :class:`~offline.sim.actuators.Actuators`:
             its rate limit, range and the scenario's failures) against the capped commands'
             servo angle minus the believed one.

        Terms of one family (a wheel's three speed terms) are never combined, so one of them
        matters beside the family's best only as its look-alike, which must reach 75 % of the
        best's held-out improvement: a term whose free score is below :data:`SCREEN_FAMILY_FRACTION`
        (a quarter) of its family's best is not fitted either (a servo lag scores 7 on the
        encoder of a wheel whose cap scores 476).

        Without that encoder (no ``omega_W`` channel, no steering readings) a term is fitted when
        a located region lies on one of its wheel's channels (``omega_W``, ``torque_W``). A
        located region on the wheel's channels without an encoder score (a hub dragging on that
        wheel's torque while its servo holds the speed) does not implicate the servo. Otherwise
        the term is left out of the library's test; the reason is reported either way.
        """
        from scipy.stats import chi2 as _chi2

        need = SCREEN_FRACTION * float(_chi2.ppf(1.0 - alpha, 1))
        params = model.params
        rs = params.wheel.shearing_radius
        believed = [model.servo_steer(d, d.rim_cmd, d.steer_cmd) for d in self.drives]
        wheels = model.wheels  # the believed rover's (the mini rover's FR, FL, RR, RL or a rover file's)

        def speed_dz(i: int, w: str, terms: Mapping[str, float]) -> NDArray[np.float64]:
            # the omega_W rows moved by the terms' change of wheel i's rim-speed command (test units)
            ch = f"omega_{w}"
            dz = np.zeros(len(self))
            for k, (d, seg) in enumerate(zip(self.drives, self.segments)):
                rim, _ = actuator_commands(terms, d.rim_cmd, d.steer_cmd, d.period, wheels)
                dom = (rim[:, i] - d.rim_cmd[:, i]) / rs
                dom = np.concatenate([dom[:1], dom[:-1]])  # tick j follows the command of tick j - 1
                rows = np.flatnonzero(self.drive == k)
                means = np.array([dom[a + 1:b + 1].mean() for a, b in seg.bounds])
                dz[rows] = means[self.segment[rows]] / (self.noise[ch][rows] * scale[ch])
            return dz

        out: dict[str, tuple[bool, str, tuple[float, ...] | None]] = {}
        scores: dict[str, tuple[str, float]] = {}
        chans = list(self.channels)
        best_speed: dict[str, tuple[float, dict[str, float]]] = {}  # wheel: (free score, terms at its best value)
        # the slew last: it is scored on top of its wheel's best speed term
        for c in sorted(candidates, key=lambda c: c.family.startswith("slew_")):
            kind, _, w = c.family.partition("_")
            if kind not in ("speed", "slew", "steer") or w not in wheels:
                out[c.key] = (True, "not a per-wheel actuator term: always fitted", None)
                continue
            hit = [r.channel for r in regions if r.channel in (f"omega_{w}", f"torque_{w}")]
            where = f"; located regions on {', '.join(sorted(set(hit)))}" if hit else ""
            if (f"omega_{w}" not in chans if kind != "steer" else any(d.steer_reading is None for d in self.drives)):
                out[c.key] = (bool(hit), ("no encoder to score it" + (where or "; no located region on the wheel's channels")), None)
                continue
            i = wheels.index(w)
            grid = np.unique(np.concatenate([np.linspace(c.lower[0], c.upper[0], SCREEN_GRID),
                                             [s[0] for s in c.starts], [c.params[0][4]]]))
            best, arg = -math.inf, float(grid[0])
            on_top = best_speed.get(w, (-math.inf, {}))
            base_terms = on_top[1] if kind == "slew" and on_top[0] >= need else {}
            base_dz = speed_dz(i, w, base_terms) if kind == "slew" else None
            for th in grid:
                terms = rover_terms(c.build(np.array([th]) * c.to_si, params))
                if kind != "steer":
                    z = z0[:, chans.index(f"omega_{w}")]
                    dz = speed_dz(i, w, {**base_terms, **terms})
                    if base_dz is not None:  # the slew's gain beyond its wheel's best speed term
                        z, dz = z - base_dz, dz - base_dz
                    ok = np.isfinite(z) & np.isfinite(dz)
                    g = float(np.sum(z[ok] ** 2 - (z[ok] - dz[ok]) ** 2))
                else:
                    g = 0.0
                    for d, b in zip(self.drives, believed):
                        assert d.steer_reading is not None
                        rim, st = actuator_commands(terms, d.rim_cmd, d.steer_cmd, d.period, wheels)
                        e = d.steer_reading[:, i] - b[:, i]
                        de = model.servo_steer(d, rim, st)[:, i] - b[:, i]
                        sel = np.isfinite(e)
                        if sel.sum() < 3:
                            continue
                        sig = max(_difference_sigma(e[sel]), 1e-5)
                        g += float(np.sum(e[sel] ** 2 - (e[sel] - de[sel]) ** 2)) / sig**2
                if g > best:
                    best, arg = g, float(th)
            enc = "steering encoder" if kind == "steer" else "wheel-speed encoder"
            if base_terms:
                enc += " on top of " + ", ".join(f"{k} = {x:.4g}" for k, x in base_terms.items())
            out[c.key] = (bool(best >= need), f"free score on the {enc} {best:.3g} at {c.params[0][0]} {arg:.3g} "
                                              f"{c.params[0][1]} {'>=' if best >= need else '<'} {need:.3g}{where}", (arg,))
            scores[c.key] = (c.family, best)
            if kind == "speed" and best > best_speed.get(w, (-math.inf, {}))[0]:
                best_speed[w] = (best, dict(rover_terms(c.build(np.array([arg]) * c.to_si, params))))
        for key, (fam, g) in scores.items():
            top = max(v for f, v in scores.values() if f == fam)
            if out[key][0] and g < SCREEN_FAMILY_FRACTION * top:
                out[key] = (False, out[key][1] + f", below {SCREEN_FAMILY_FRACTION:g} of its family's best ({top:.3g})",
                            out[key][2])
        return out

    def folds(self, k: int) -> NDArray[np.int_]:
        """Held-out time segments: each drive cut into ``k`` contiguous blocks of time (fold = block)."""
        out = np.empty(len(self), dtype=int)
        for d in np.unique(self.drive):
            rows = np.flatnonzero(self.drive == d)
            order = rows[np.argsort(self.segment[rows])]
            out[order] = (np.arange(order.size) * k) // order.size
        return out

    def probes(self) -> list[Probe]:
        """What-if drives that separate explanations: the same commands on the terrain turned by 90
        and by 180 deg (a world-fixed slope turns with the heading in the rover's frame; a body-fixed
        tether, a mounting tilt or a wheel defect do not)."""
        return [Probe("drive the same commands with the rover turned 180 deg on the terrain (opposite heading)",
                      replace(self, heading_offset=self.heading_offset + math.pi)),
                Probe("drive the same commands with the rover turned 90 deg on the terrain",
                      replace(self, heading_offset=self.heading_offset + math.pi / 2))]


@dataclass
class DriveModel:
    """The believed simulator of a rover drive: scenario (parameter set, rover, failures), a believed
    world, actuators and sensor biases; ``predict(observations, extension)`` for the engine.

    Parameters
    ----------
    scenario : Scenario
    truth : Truth, optional
        The believed world (default: the scenario's parameters, flat, nominal wheels).
    actuators : ActuatorConfig, optional
    sensors : SensorConfig, optional
        Only the believed biases are used (gyro bias, IMU mounting); predictions are noise-free.
    stride : int
        In steady stretches (commands unchanged, servos settled) the plant is solved every
        ``stride`` ticks and the readings in between interpolated linearly; around every command
        change and while the servos move (steering slew, speed lag) it is solved at every tick.
        The actuators follow every tick's commands. At drive speeds the plant is quasi-static,
        so the interpolation error is that of a slowly turning gravity vector.
    halvings : int
        A tick whose plant step fails (the simulator's own retries included) is tried again in
        halves at most this many times before it is lost (:func:`_step`; 0: not tried again).
    cache_size : int
        Re-simulated drives kept (keyed by the drive, heading offset and the extension's
        physics; a soil field at the believed value and a rover term at its neutral value,
        :data:`~offline.discrepancy.drive.candidates.NEUTRAL_VALUES`, are left out of the key), least
        recently used dropped first. A diagnosis re-simulates a 40 s drive 400-800 times at about
        25 kB each, so the default keeps them all: the held-out refits start where the full-data
        fits started, the null's linearisation points and the forward step's score test sit on
        fitted points, and each of those is simulated once.
    """

    scenario: Scenario
    truth: Truth | None = None
    actuators: ActuatorConfig | None = None
    sensors: SensorConfig | None = None
    cache_size: int = 2048
    stride: int = 3
    halvings: int = 0
    _cache: dict[Any, Any] = field(default_factory=dict, init=False, repr=False)
    _runs: list[tuple[Any, bool]] = field(default_factory=list, init=False, repr=False)
    simulations: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if getattr(self.scenario, "rover_file", None) is not None:
            self._rover_file_defaults()
        if self.truth is None:
            self.truth = Truth.nominal(self.scenario.params, self.scenario.rover)
        self.actuators = self.actuators or ActuatorConfig()
        self.sensors = self.sensors or SensorConfig()

    def _rover_file_defaults(self) -> None:
        """A rover file's believed world and servos (issue 23): the simulator's own defaults for it
        (:func:`offline.sim.simulator.rover_file_truth`, :func:`~offline.sim.simulator.rover_file_actuators`),
        so the re-simulation is the rover's as the recording's simulator ran it."""
        from ...sim.simulator import rover_file_actuators, rover_file_truth, suspension_plant_for

        sc = self.scenario
        spec = sc.rover_file
        if spec is None:
            raise DriveDataError(f"scenario {sc.name} names no rover file")
        if self.truth is None:
            self.truth = rover_file_truth(sc, suspension_plant_for(sc.params, spec, sc.exit_angle))
        if len(self.truth.wheel_radius) != len(self.wheels):
            raise DriveDataError(f"the believed world has {len(self.truth.wheel_radius)} wheel radii; the rover of "
                                 f"scenario {sc.name} has {len(self.wheels)} wheels ({', '.join(self.wheels)})")
        if self.actuators is None:
            self.actuators = rover_file_actuators(spec, sc.params.wheel.shearing_radius)

    @property
    def wheels(self) -> tuple[str, ...]:
        """The believed rover's wheels (the scenario's: the mini rover's or a rover file's), in the
        order of every per-wheel column."""
        return tuple(self.scenario.wheels)

    @property
    def params(self) -> ParameterSet:
        """The believed parameter set (candidates scale its soil)."""
        assert self.truth is not None
        return self.truth.params

    def lookalike_probes(self) -> tuple[Any, ...]:
        """Probes of the engine's identifiability rule (step 6 of :mod:`offline.discrepancy.engine`):
        a pull at the body, the same drag at every wheel, a soil k scale, sized for this rover
        (:func:`~offline.discrepancy.drive.candidates.lookalike_probes`)."""
        from .candidates import lookalike_probes

        return lookalike_probes(self.scenario)

    @staticmethod
    def wrench_claim(key: str) -> str | None:
        """What a candidate that can give a drive's body wrench claims
        (:data:`~offline.discrepancy.drive.candidates.WRENCH_LOOKALIKES`); None for any other."""
        from .candidates import WRENCH_LOOKALIKES

        return WRENCH_LOOKALIKES.get(key)

    @staticmethod
    def separating_manoeuvres(a: str, b: str) -> str:
        """The manoeuvres that separate two claims of :meth:`wrench_claim`
        (:data:`~offline.discrepancy.drive.candidates.SEPARATING_MANOEUVRES`)."""
        from .candidates import SEPARATING_MANOEUVRES

        return SEPARATING_MANOEUVRES.get(frozenset({a, b}), "a turn, a drive in the other direction or a change of slope")

    def simulate(self, d: DriveData, ext: RoverExtension | None, heading_offset: float, extra: Any = None
                 ) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64], bool]:
        """Re-simulate one drive (module notes): predicted tick readings, body velocities (n, 3), ok.

        Cached per drive, heading offset and the extension's physics (measurement-chain terms are
        applied afterwards, so they cost no re-simulation). ``extra``: an empirical term
        (:class:`offline.discrepancy.drive.empirical.EmpiricalTerms`) applied on top of the extension: its
        ``hook(time_of, pose_of)`` (a disturbance hook or None), ``commands(rim, steer, t)`` (the
        commands the servos really follow) and ``readings(ticks, t)`` (reading offsets), keyed by
        its ``key()``.
        """
        ext = ext or RoverExtension()
        terms = rover_terms(ext)
        believed = self.params.soil
        soil = tuple(sorted((k, v) for k, v in ext.soil.items() if getattr(believed, k, math.nan) != v))
        key = (id(d), heading_offset, soil, terms.physics_key(), extra.key() if extra is not None else None)
        hit = self._cache.pop(key, None)
        if hit is None:
            before = self.simulations
            hit = self._run(d, ext, heading_offset, extra)
            self._runs.append((key, self.simulations > before))
            self._trim()
        self._cache[key] = hit  # most recently used last
        ticks, body, ok = hit
        if not ok:
            return ticks, body, False
        out = dict(ticks)
        g = terms.get("gyro_scale", 0.0)
        if g:
            b = self.sensors.gyro_bias  # type: ignore[union-attr]
            out["yaw_rate"] = (ticks["yaw_rate"] - b) * (1.0 + g) + b
        out["roll"] = ticks["roll"] + terms.get("imu_roll", 0.0)
        out["pitch"] = ticks["pitch"] + terms.get("imu_pitch", 0.0)
        if extra is not None:
            out = extra.readings(out, d.t)
        return out, body, True

    def _trim(self) -> None:
        while len(self._cache) >= max(self.cache_size, 1):
            self._cache.pop(next(iter(self._cache)))

    def work_mark(self) -> int:
        """A mark of the re-simulations run so far (:func:`offline.discrepancy.parallel.map_tasks`)."""
        return len(self._runs)

    def work_since(self, mark: int) -> list[tuple[Any, bool, Any]]:
        """The re-simulations run since ``mark``: (cache key, counted in :attr:`simulations`, result)."""
        return [(k, counted, self._cache.get(k)) for k, counted in self._runs[mark:]]

    def absorb(self, work: Sequence[tuple[Any, bool, Any]]) -> None:
        """Take re-simulations a worker process ran (:meth:`work_since`), in task order.

        One this model already holds (an earlier task ran it: the serial loop would have found it
        in the cache) is neither stored nor counted again, so :attr:`simulations` and the cache
        are those of the serial loop (with the default ``cache_size`` nothing is dropped from it).
        The keys name drives by ``id``: a worker re-simulates the drives of the forked parent,
        whose ids are this process's.
        """
        for key, counted, hit in work:
            if key in self._cache:
                continue
            self._runs.append((key, counted))
            self.simulations += int(counted)
            if hit is not None:
                self._trim()
                self._cache[key] = hit

    def servo_steer(self, d: DriveData, rim_cmd: NDArray[np.float64], steer_cmd: NDArray[np.float64]) -> NDArray[np.float64]:
        """The steering servos' angles at the ticks (n, wheels; rad) for these per-tick commands: the
        simulator's own servo (:class:`~offline.sim.actuators.Actuators`: rate limit, range, the
        scenario's failures) started settled at the first commands and moved one command period
        per tick by the previous tick's commands, as the re-simulation and the recording do. No
        plant solve."""
        assert self.actuators is not None
        acts = Actuators(self.actuators, dict(self.scenario.failures), self.params.wheel.shearing_radius, wheels=self.wheels)
        acts.reset(tuple(rim_cmd[0]), tuple(steer_cmd[0]))
        out = np.empty((len(d.t), len(self.wheels)))
        out[0] = acts.steer
        for k in range(1, len(d.t)):
            acts.command(tuple(rim_cmd[k - 1]), tuple(steer_cmd[k - 1]))
            acts.advance(d.period)
            out[k] = acts.steer
        return out

    def _run(self, d: DriveData, ext: RoverExtension, heading_offset: float, extra: Any = None
             ) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64], bool]:
        assert self.truth is not None and self.sensors is not None and self.actuators is not None
        n, wheels = len(d.t), self.wheels
        ticks = {c: np.full(n, np.nan) for c in tick_channels(wheels)}
        body = np.full((n, 3), np.nan)
        try:
            truth, act, _ = truth_from_terms(self.params, self.truth, ext, wheels)
            # pose-dependent hooks (an anchored tether) see the recorded pose of the tick being solved
            # (the simulator's own clock skips the ticks interpolated in steady stretches)
            path, clock = _recorded_pose(d), [0.0]
            hook = disturbance_from_terms(ext, self.params, self.scenario.rover_file or self.scenario.rover,
                                          None if path is None else (lambda t: path(clock[0])))
            if extra is not None:
                more = extra.hook(lambda: clock[0], lambda tt: (float(np.interp(tt, d.t, d.pose[:, 0])),
                                                                float(np.interp(tt, d.t, d.pose[:, 1])),
                                                                float(np.interp(tt, d.t, d.pose[:, 2]))))
                if more is not None:
                    hook = more if hook is None else _sum_hooks(hook, more)
        except ValueError:
            return ticks, body, False
        acfg = replace(self.actuators, **act) if act else self.actuators
        s = self.sensors
        sens = SensorConfig(wheel_speed_noise=0.0, steer_noise=0.0, gyro_bias=s.gyro_bias, gyro_noise=0.0, tilt_noise=0.0,
                            tilt_offset=s.tilt_offset, torque_noise=0.0, pose_period=math.inf, gyro_bias_walk=0.0)
        self.simulations += 1
        try:
            sim = RoverSimulator(self.scenario, truth, actuators=acfg, sensors=sens, dt=d.period, seed=0, disturbance=hook)
            # a backward drive (issue 23) runs its plant in the travel frame, its readings in the body frame
            # (:meth:`RoverSimulator.measure`): the travel heading is the body's plus pi, the body
            # velocities and the servo speeds change sign (yaw rate: the same)
            hd = d.pose[:, 2] + heading_offset
            if sim.backward:
                hd = hd + math.pi
            flip = np.array([-1.0, -1.0, 1.0]) if sim.backward else np.ones(3)
            sim.heading = float(hd[0])
            # the commands each wheel's servos really follow (per-wheel actuator terms)
            rim_cmd, steer_cmd = actuator_commands(rover_terms(ext), d.rim_cmd, d.steer_cmd, d.period, wheels)
            if extra is not None:
                rim_cmd, steer_cmd = extra.commands(rim_cmd, steer_cmd, d.t)
            sim.start(Commands(0.0, 0, tuple(rim_cmd[0]), tuple(steer_cmd[0])))

            servo, omega = np.full((n, len(wheels)), np.nan), np.full((n, len(wheels)), np.nan)
            failed = np.zeros(n, dtype=bool)

            def record(k: int) -> None:
                m = sim.measure()
                for i, w in enumerate(wheels):
                    ticks[f"omega_{w}"][k] = m.wheel_speed[i]
                    ticks[f"torque_{w}"][k] = m.motor_torque[i]  # type: ignore[index]
                ticks["yaw_rate"][k], ticks["roll"][k], ticks["pitch"][k] = m.yaw_rate, m.roll, m.pitch
                body[k] = sim.z[:3] * flip
                servo[k] = sim.act.omega_servo * flip[0]
                omega[k] = m.wheel_speed

            record(0)
            cmd = np.hstack([rim_cmd, steer_cmd])
            acts = sim.act
            solved, settled = [0], True
            for k in range(1, n):
                c = rim_cmd[k - 1], steer_cmd[k - 1]
                sim.apply(Commands(float(d.t[k - 1]), k - 1, tuple(c[0]), tuple(c[1])))
                steady = settled and (k < 2 or bool(np.all(cmd[k - 1] == cmd[k - 2])))
                last_of_regime = k < n - 1 and bool(np.any(cmd[k] != cmd[k - 1]))
                if steady and not last_of_regime and k % self.stride and k != n - 1:
                    acts.advance(d.period)  # actuators follow every tick; the plant is solved where needed
                    servo[k] = acts.omega_servo * flip[0]
                    continue
                sim.heading = float(hd[k])
                clock[0] = float(d.t[k])
                steer_before = acts.steer.copy()
                try:
                    _step(sim, d.period, halvings=self.halvings)
                except SimulationError:
                    # no equilibrium (e.g. a wheel speed through zero with a slow servo): this tick
                    # is lost and the plant restarts from the steady state of these commands
                    failed[k] = True
                    if failed.sum() > 0.5 * n:
                        # more than half the ticks lost: the drive is not re-simulated whatever the
                        # rest does (the check below), and its callers discard what it holds, so the
                        # rest is not simulated (a parameter far outside what the plant can carry
                        # costs up to four failing 40-iteration Newton solves per tick)
                        return ticks, body, False
                    sim.start(Commands(float(d.t[k - 1]), k - 1, tuple(c[0]), tuple(c[1])))
                    settled = False
                    continue
                sim.heading = float(hd[k])
                record(k)
                solved.append(k)
                settled = bool(np.allclose(acts.steer, steer_before, rtol=0, atol=1e-9)
                               and np.allclose(acts.omega_servo, acts.omega_cmd, rtol=1e-3, atol=1e-6))
            for ch, v in ticks.items():
                ticks[ch] = np.interp(np.arange(n), solved, v[solved])
            for i, w in enumerate(wheels):  # wheel speed: the servo's every tick, plus what the plant changed
                ch = f"omega_{w}"
                ticks[ch] = servo[:, i] + np.interp(np.arange(n), solved, (omega[solved, i] - servo[solved, i]))
            for j in range(3):
                body[:, j] = np.interp(np.arange(n), solved, body[solved, j])
        except (SimulationError, ValueError):
            return ticks, body, False
        if failed.mean() > 0.5:
            return ticks, body, False
        for v in ticks.values():
            v[failed] = np.nan
        body[failed] = np.nan
        return ticks, body, True

    def predict(self, obs: DriveRecording, ext: RoverExtension | None = None, extra: Any = None
                ) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
        """Predicted channels of every row of ``obs`` (NaN and ``ok = False`` where the re-simulation
        fails); ``extra``: an empirical term on top of ``ext`` (:meth:`simulate`)."""
        out = {c: np.full(len(obs), np.nan) for c in obs.channels}
        ok = np.zeros(len(obs), dtype=bool)
        for k in np.unique(obs.drive):
            d, seg = obs.drives[k], obs.segments[k]
            ticks, body, good = self.simulate(d, ext, obs.heading_offset, extra)
            rows = np.flatnonzero(obs.drive == k)
            if not good:
                continue
            table = _rows_from_ticks(d, seg, ticks, body, obs.channels)
            for c, ch in enumerate(obs.channels):
                out[ch][rows] = table[obs.segment[rows], c]
            ok[rows] = np.all(np.isfinite(table[obs.segment[rows]]), axis=1)
        return out, ok

    def empty_extension(self) -> RoverExtension:
        """The extension that changes nothing (the engine merges candidates onto it)."""
        return RoverExtension()

    def recalibration(self) -> Any:
        """The soil recalibration candidate (:func:`offline.discrepancy.drive.candidates.recalibration_candidate`)."""
        return library_for([recalibration_candidate(self.params)], self.scenario)[0]

    def parameter_set(self, ext: RoverExtension, note: str = "") -> ParameterSet:
        """The believed parameter set with the extension's soil changes (for "parameters off")."""
        p = self.params
        soil = replace(p.soil, **ext.soil, name=f"{p.soil.name}_recalibrated", source="offline.discrepancy.drive.diagnosis")
        return replace(p, soil=soil, notes=note or p.notes)

    def describe(self) -> str:
        """One line naming the believed model."""
        p = self.params
        return (f"rover `{self.scenario.rover.name}`, soil `{p.soil.name}`, wheel `{p.wheel.name}` "
                f"(r = {1e3 * p.wheel.radius:.1f} mm), scenario `{self.scenario.name}`, re-simulated by "
                "offline.sim.RoverSimulator with the recorded commands and the recorded heading")


def diagnose_drives(
    paths: Sequence[str | Path], scenario: Scenario, truth: Truth | None = None, actuators: ActuatorConfig | None = None,
    sensors: SensorConfig | None = None, segment: int = 5, k_folds: int = 5, alpha: float = DRIVE_ALPHA,
    n_boot: int | None = None,
    n_points: int = 2, max_nfev: int = 8, stride: int = 3, seed: int = 0, candidates: Sequence[Any] = DRIVE_CANDIDATES,
    recalibrate: bool = True, max_tries: int = 3, fit_tol: float | None = 1e-4,
    progress: Callable[[str], None] | None = None, alpha_after: float = DRIVE_ALPHA_AFTER, empirical: bool = True,
    workers: int = 1,
) -> Verdict:
    """Locate, name and fit the missing physics of recorded drives (module notes) with the engine.

    Parameters
    ----------
    paths : sequence of path
        MCAP recordings or folders of them.
    scenario : Scenario
        The believed rover, parameter set and declared failures.
    truth, actuators, sensors
        The believed world, actuator limits and sensor biases (defaults: flat nominal world,
        :class:`ActuatorConfig`, :class:`SensorConfig`).
    segment : int
        Ticks per row.
    max_tries : int
        Candidates tried on top of the first explanation (a tether under a slope ranks third on its
        own, behind the IMU tilt that mimics the slope's roll and pitch).
    candidates, recalibrate
        The library (default :data:`~offline.discrepancy.drive.candidates.DRIVE_CANDIDATES`: its
        per-wheel actuator terms are screened, fitted only on the wheels whose own encoders
        implicate them, :meth:`DriveRecording.screen`; the verdict lists the screen) and whether
        the soil recalibration joins it.
    stride : int
        Plant solved every ``stride`` ticks (:class:`DriveModel`).
    alpha : float
        Family-wise false-alarm level of each test (default :data:`DRIVE_ALPHA`); the region
        test runs at ``alpha`` / channels.
    alpha_after : float
        Level of the checks of what an accepted explanation leaves (regions and lack of fit;
        default :data:`DRIVE_ALPHA_AFTER`).
    n_boot : int, optional
        Monte-Carlo draws of the candidate test (default ``ceil(3 / alpha)``: the smallest
        attainable p-value, ``1 / (n_boot + 1)``, must lie below ``alpha``; fewer than
        ``1 / alpha`` is refused, since no candidate could then be significant).
    k_folds, n_points, max_nfev, seed, fit_tol
        Passed to :func:`offline.discrepancy.engine.diagnose` (``max_nfev`` least-squares
        iterations per start: budget in iterations; ``fit_tol`` 1e-4: a fit stops once the
        chi-square changes by less than 1e-4 of itself, about 0.05 on a 40 s drive, which no
        held-out comparison resolves); the forward step for a second term always runs
        (``forward="always"``).
    progress : callable, optional
        Called with a short message at each stage of the diagnosis.
    empirical : bool
        When the library does not explain the drive (verdict ``unexplained``, ``ambiguous`` or
        ``partly_explained``), model what it lacks with the generic empirical family
        (:func:`offline.discrepancy.drive.empirical.search_empirical`, same seed and level); the result
        is ``verdict.empirical`` and the library's verdict is kept (a rover file's recording: the
        terms on its own wheels, issue 23).
    workers : int
        Processes the independent re-simulations run on (:func:`offline.discrepancy.engine.diagnose`);
        the verdict does not depend on it, bit for bit. 1 (default): this process; the command
        line takes every core (``--workers``).

    Returns
    -------
    Verdict
        The engine's verdict; ``verdict.model`` is the :class:`DriveModel`.
    """
    if not (0.0 < alpha < 0.5):
        raise ValueError(f"alpha = {alpha}: a false-alarm level between 0 and 0.5 is expected (default {DRIVE_ALPHA})")
    n_boot = int(math.ceil(3.0 / alpha)) if n_boot is None else int(n_boot)
    if n_boot + 1 < 1.0 / alpha:
        raise ValueError(f"n_boot = {n_boot} at alpha = {alpha}: the smallest attainable p-value 1 / (n_boot + 1) = "
                         f"{1.0 / (n_boot + 1):.2g} is above the level, so nothing could be significant; use at least "
                         f"{int(math.ceil(1.0 / alpha))} draws (default 3 / alpha) or a larger alpha")
    model = DriveModel(scenario, truth, actuators, sensors, stride=stride)
    candidates = library_for(candidates, scenario)  # the rover's wheels (the mini rover's: as given)
    assert model.sensors is not None
    drives = load_drives(paths, model.sensors.gyro_bias)
    obs = replace(DriveRecording.build(drives, model, segment), family_alpha=alpha)
    v = diagnose(obs, model, candidates=candidates, recalibrate=recalibrate, k_folds=k_folds, alpha=alpha, n_boot=n_boot,
                 n_points=n_points, max_nfev=max_nfev, max_tries=max_tries, seed=seed, progress=progress,
                 forward="always", fit_tol=fit_tol, alpha_after=max(alpha_after, alpha), forward_extra=False,
                 polish_nfev=0, workers=workers, refit_in_turn=True)
    if empirical and v.status in ("unexplained", "ambiguous", "partly_explained"):
        from .empirical import search_empirical

        t0 = time.perf_counter()
        v.empirical = search_empirical(v, alpha=alpha, seed=seed, k_folds=k_folds, progress=progress,
                                       alpha_after=max(alpha_after, alpha))
        v.seconds += time.perf_counter() - t0
    return v


def accepted_extension(v: Verdict) -> RoverExtension:
    """The extension of the accepted explanation (no change for ``agree`` and ``unexplained``)."""
    c = v.chosen
    if c is None or v.status in ("agree", "unexplained", "ambiguous"):
        return RoverExtension()
    model: DriveModel = v.model
    lib = {x.key: x for x in [*library_for(DRIVE_CANDIDATES, model.scenario), model.recalibration()]}
    e, i = RoverExtension(), 0
    for k in c.keys:
        cand = lib[k]
        e = e.merge(cand.build(np.array(c.values[i:i + cand.k]) * cand.to_si, model.params))
        i += cand.k
    return e


def held_out_drives(v: Verdict, paths: Sequence[str | Path]) -> dict[str, float]:
    """Score the accepted explanation on drives it was not fitted on.

    The drives are segmented and their noise estimated exactly as the fitted ones; the model as
    given and the model with the accepted extension (parameters fitted on the first drives)
    predict them. Returns the chi-square (normalised by noise and the verdict's dispersion)
    before and after, and the number of rows.
    """
    model: DriveModel = v.model
    obs = DriveRecording.build(load_drives(paths, model.sensors.gyro_bias if model.sensors else 0.0), model,
                               segment=int(v.observations.segments[0].bounds[0, 1] - v.observations.segments[0].bounds[0, 0]))
    out = {"rows": float(len(obs) * len(obs.channels))}
    for label, e in (("before", None), ("after", accepted_extension(v))):
        pred, _ = model.predict(obs, e)
        out[f"chi2_{label}"] = float((normalised(obs, pred, v.scale) ** 2).sum())
    return out

"""Simulator commands: ``drive`` (a closed-loop drive, or the section 7.3 experiments) and ``replay``
(a recording through rtctl, bit for bit; optionally hardware-in-the-loop style)."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from .common import fail

__all__ = ["register"]

DEFAULT_SCENARIO = "rr_steer_stuck_50"
MISMATCH_TRUTHS = ("soil_soft_30", "soil_stiff_30", "slope_5deg")
"""Shipped truths of the issue's model-mismatch runs (plus pose fixes only every 10 s)."""


def _sensor_config(args: argparse.Namespace) -> Any:
    from ..sim.sensors import SensorConfig

    kw: dict[str, Any] = {}
    if args.pose_period is not None:
        kw["pose_period"] = math.inf if args.pose_period <= 0 else args.pose_period
    if args.pose_delay is not None:
        kw["pose_delay"] = args.pose_delay
    return SensorConfig(**kw)


def _metrics_table(rows: list[dict[str, Any]]) -> str:
    head = ("| scenario | truth | controller | final heading [deg] | max abs heading [deg] | final y [cm] | max abs y [cm] "
            "| mean speed [cm/s] | speed error [%] | distance [m] | time [s] |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        m = r["metrics"]
        lines.append(f"| {r['scenario']} | {r['truth']} | {r['controller']} | {m['final_heading_deg']:.2f} | {m['max_abs_heading_deg']:.2f} | "
                     f"{m['final_cross_track_cm']:.2f} | {m['max_abs_cross_track_cm']:.2f} | {m['mean_speed_cm_s']:.2f} | "
                     f"{m['speed_error_pct']:+.1f} | {m['distance_m']:.2f} | {m['time_s']:.1f}"
                     + (" (STUCK)" if "stuck" in r else " (ENDED EARLY)" if "ended" in r else "") + " |")
    return "\n".join(lines)


class _TracedPlant:
    """The simulator seen by the HIL runner, keeping the truth and measurements of every tick."""

    def __init__(self, sim: Any) -> None:
        from ..sim.experiments import declared_task

        self.sim = sim
        self.truth: list[Any] = []
        self.measurements: list[Any] = []
        self.task = declared_task(sim.scenario)

    def measure(self) -> Any:
        from ..sim.experiments import with_task

        m = with_task(self.sim.measure(), self.task)
        self.measurements.append(m)
        self.truth.append(self.sim.truth_state())
        return m

    def apply(self, commands: Any) -> None:
        self.sim.apply(commands)

    def advance(self, seconds: float) -> None:
        self.sim.advance(seconds)


def _hil_drive(args: argparse.Namespace, sim: Any, ctl: Any, kind: str, meta: dict[str, Any], rec_path: Path) -> Any:
    """rtctl in its own process at the real 5 Hz clock driving the simulator (deadline misses counted)."""
    import functools

    from rtctl.hil import run_hil
    from rtctl.recording import Recorder

    from ..sim.experiments import DriveResult, _first_measurement, drive_metrics, trench_metrics
    from ..sim.rtctl_bridge import rtctl_controller

    c0, _ = ctl.step(_first_measurement(sim))
    sim.start(c0)
    plant = _TracedPlant(sim)
    x0 = 0.0
    factory = functools.partial(rtctl_controller, args.tables, args.config, sim.scenario.speed)
    max_ticks = int(math.ceil(3.0 * args.distance / sim.scenario.speed / 0.2)) + 1
    rep = run_hil(factory, plant=plant, ticks=max_ticks, until=lambda: plant.truth[-1].x - x0 >= args.distance)
    res = DriveResult(sim.scenario.name, f"{kind} (HIL)", plant.truth, [c for c in rep.commands if c is not None])
    res.metrics = drive_metrics(plant.truth, sim.scenario.speed)
    res.metrics.update(trench_metrics(plant.truth, sim.scenario, sim.truth.params))
    res.metrics["deadline_misses"] = float(rep.deadline_misses)
    res.step_seconds = rep.step_times
    st = rep.stats()["step"]
    print(f"HIL {sim.scenario.name}: rtctl in its own process, {rep.ticks} ticks at 5 Hz, {rep.deadline_misses} deadline "
          f"misses (200 ms), step median {1e6 * st['median_s']:.0f} us, max {1e6 * st['max_s']:.0f} us", flush=True)
    if not args.no_record:
        from rtctl.recording import provenance

        with Recorder(rec_path, {**meta, "hil": True, "deadline_misses": rep.deadline_misses}, truth=True,
                      provenance=provenance(ctl), wheels=sim.wheels if sim.rover_file is not None else None) as rec:
            for i, (m, ts) in enumerate(zip(plant.measurements, plant.truth)):
                rec.measurements(m)
                if i < len(rep.commands) and rep.commands[i] is not None:
                    rec.commands(rep.commands[i])
                    rec.timing(m.t, m.seq, rep.step_times[i], 0.2, missed=m.seq in rep.late_seqs)
                rec.truth(m.t, ts)
    return res


def _truth_hooks(truth: Any, scenario: Any) -> Any:
    """The disturbance hook of a truth file's ``[tether_anchor]`` / ``[hub_contact]`` /
    ``[[empirical_force]]`` on the scenario's rover (the mini rover's or a rover file's wheels;
    None without them)."""
    if truth.anchor is None and truth.hub is None and not truth.empirical:
        return None
    from ..discrepancy.drive.candidates import disturbance_from_truth
    from ..discrepancy.drive.wheel_set import truth_disturbance

    if not hasattr(scenario, "rover_file"):  # the mini rover's Rover itself (the earlier signature)
        return disturbance_from_truth(truth, scenario)
    return truth_disturbance(truth, scenario)


def _cmd_drive(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from rtctl.recording import Recorder, provenance

    from ..files import OutputError, check_output_dir, write_text
    from ..sim.actuators import ActuatorError
    from ..sim.experiments import (DISSERTATION_7_3, SECTION_7_3, ExperimentError, build_controller, plot_runs,
                                   run_drive, scenario_by_name)
    from ..sim.plant import SimulationError
    from ..sim.rtctl_bridge import RtctlUnavailable, rtctl_factory
    from ..sim.simulator import RoverSimulator
    from ..sim.truth import Truth, TruthError, load_truth, resolve_truth_path

    if args.section_7_3:
        plan = {k: list(v) + (["rtctl"] if args.with_rtctl else []) for k, v in SECTION_7_3.items()}
    else:
        ctrls = [c.strip() for c in args.controllers.split(",") if c.strip()]
        plan = {args.scenario or DEFAULT_SCENARIO: ctrls}
    # truths: (label, truth file or None, pose period or None)
    variants: list[tuple[str, str | None, float | None]] = [("believed" if not args.truth else Path(args.truth).stem,
                                                            args.truth, None)]
    if args.mismatch:
        variants += [(n, n, None) for n in MISMATCH_TRUTHS] + [("pose_every_10s", args.truth, 10.0)]
    out = Path(args.out)
    try:
        check_output_dir(out, inputs=[args.truth, args.tables, args.config])
    except OutputError as exc:
        return fail(str(exc))
    factory = None
    if any("rtctl" in c for c in plan.values()):
        try:
            factory = rtctl_factory(args.tables, args.config)
        except RtctlUnavailable as exc:
            return fail(str(exc))
    rows: list[dict[str, Any]] = []
    total = sum(len(v) for v in plan.values()) * len(variants)
    bar = tqdm(total=total, desc="drives", unit="drive", disable=args.quiet)
    for name, ctrls in plan.items():
        for label, truth_file, pose_period in variants:
            try:
                sc = scenario_by_name(name)
                truth = (load_truth(resolve_truth_path(truth_file), sc.rover_file or sc.rover, sc.params) if truth_file
                         else Truth.nominal(sc.params, sc.rover) if sc.rover_file is None
                         else None)  # a rover file's world: the simulator's rover_file_truth
            except (ExperimentError, TruthError) as exc:
                bar.close()
                return fail(str(exc))
            sensors = _sensor_config(args)
            if pose_period is not None:
                sensors = replace(sensors, pose_period=pose_period)
            tag = "" if len(variants) == 1 else f"_{label}"
            runs = []
            for kind in ctrls:
                bar.set_postfix_str(f"{name} / {label} / {kind}")
                try:
                    ctl = build_controller(kind, sc, rtctl_factory=factory)
                    sim = RoverSimulator(sc, truth, sensors=sensors, dt=args.dt, seed=args.seed,
                                         disturbance=None if truth is None else _truth_hooks(truth, sc))
                    meta = {"scenario": sc.name, "scenario_file": Path(sc.source).name, "controller": kind,
                            "seed": args.seed, "dt": args.dt, "truth": sim.truth.describe(), "truth_label": label,
                            "sensors": sensors.__dict__, "distance_m": args.distance}
                    if args.hil and kind == "rtctl":
                        r = _hil_drive(args, sim, ctl, kind, meta, out / f"{sc.name}{tag}_{kind}.mcap")
                    elif args.no_record:
                        r = run_drive(sim, ctl, distance=args.distance, name=kind)
                    else:
                        rec_path = out / f"{sc.name}{tag}_{kind.replace('+', '_')}.mcap"
                        wheels = sim.wheels if sc.rover_file is not None else None  # mini rover: as every recording before
                        with Recorder(rec_path, meta, truth=True, provenance=provenance(ctl), wheels=wheels) as rec:
                            r = run_drive(sim, ctl, distance=args.distance, recorder=rec, name=kind)
                except (ExperimentError, ActuatorError, SimulationError) as exc:
                    bar.close()
                    return fail(f"{name} / {label} / {kind}: {exc}")
                runs.append(r)
                rows.append({"scenario": sc.name, "truth": label, "controller": kind, "metrics": r.metrics,
                             "wall_seconds": r.wall_seconds, **({"stuck": r.stuck} if r.stuck else {}),
                             **({"ended": r.ended} if r.ended else {})})
                if r.stuck:
                    bar.write(f"{name} / {label} / {kind}: STUCK, the drive ended early: {r.stuck}")
                elif r.ended:
                    bar.write(f"{name} / {label} / {kind}: ENDED EARLY, outside what the simulator models: {r.ended}")
                bar.update(1)
            plot_runs(runs, out / f"{sc.name}{tag}.png",
                      f"{sc.name} ({label}): yaw and y error (cf. Figs. 7.6, 7.9, 7.11)")
    bar.close()
    table = _metrics_table(rows)
    notes = [f"- {k}: dissertation (hardware): {v}" for k, v in DISSERTATION_7_3.items() if k in plan]
    write_text(out / "metrics.md", "# Closed-loop drives\n\n" + table + "\n\n" + "\n".join(notes) + "\n")
    write_text(out / "metrics.json", json.dumps(rows, indent=1))
    print(table)
    for n in notes:
        print(n)
    print(f"wrote {out}/metrics.md, metrics.json, plots and {'no ' if args.no_record else ''}recordings")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    import functools

    from rtctl.hil import HilError, load_controller, run_hil
    from rtctl.recording import RecordingError, compare_provenance, export_csv, provenance, read_recording
    from rtctl.replay import ReplayError, compare_commands, replay, step_time_stats

    from ..sim.rtctl_bridge import shipped_tables

    try:
        rec = read_recording(args.recording)
    except RecordingError as exc:
        return fail(str(exc))
    if args.csv:
        files = export_csv(args.recording, args.csv)
        print("wrote " + ", ".join(str(f) for f in files))
    tables = Path(args.tables) if args.tables else shipped_tables()
    index = tables / "index.json" if tables.is_dir() else tables
    if not index.exists():
        return fail(f"{index}: no table index; pass --tables (the tables the recording was made with)")
    factory = functools.partial(load_controller, str(index), args.config)
    for name, tol in (("--rtol", args.rtol), ("--atol", args.atol)):
        if tol is not None and not (math.isfinite(tol) and tol >= 0):
            return fail(f"{name} must be finite and >= 0, got {tol}")
    tolerant = args.rtol is not None or args.atol is not None
    rtol, atol = (args.rtol or 0.0, args.atol or 0.0) if tolerant else (None, None)
    try:
        ctl = factory()
    except Exception as exc:  # the table reader's and controller's errors say what is wrong
        return fail(f"{index}: {exc}")
    refuse, warn = compare_provenance(rec.provenance, provenance(ctl))
    for w in warn:
        print(f"warning: {w}")
    if warn and not tolerant and rec.provenance:
        print("warning: another machine or library version may change the last bits; compare with --rtol/--atol "
              "for a cross-architecture bench")
    if refuse:
        msg = "; ".join(refuse)
        if not args.allow_mismatch:
            return fail(f"{args.recording}: the replaying controller is not the recorded one: {msg} (pass the "
                        "recording's tables and config, or --allow-mismatch to replay anyway)")
        print(f"warning (--allow-mismatch): the replaying controller is not the recorded one: {msg}")
    try:
        if args.hil:
            n = len(rec.measurements) if args.ticks is None else min(args.ticks, len(rec.measurements))
            print(f"HIL: rtctl in its own process, {n} ticks at 5 Hz ({0.2 * n:.0f} s) ...", flush=True)
            rep = run_hil(factory, measurements=rec.measurements[:n])
            div = [d for i, c in enumerate(rep.commands)
                   if (d := compare_commands(i, rec.commands[i], c, rtol, atol)) is not None]
            st = step_time_stats(rep.step_times)
            print(f"{rep.ticks} ticks, {rep.deadline_misses} deadline misses (200 ms), step median "
                  f"{1e6 * st['median_s']:.0f} us, p99 {1e6 * st['p99_s']:.0f} us; "
                  + ((f"commands equal within rtol {rtol:g}, atol {atol:g}" if tolerant else
                      "commands identical bit for bit") if not div else f"{len(div)} differ; first: {div[0]}"))
            return 0 if not div else 1
        r = replay(rec, ctl, rtol=rtol, atol=atol)
    except (ReplayError, HilError) as exc:
        return fail(str(exc))
    except Exception as exc:  # the table reader's and controller's errors say what is wrong
        return fail(f"{index}: {exc}")
    print(r.summary())
    return 0 if r.identical else 1


def register(sub: Any) -> None:
    """Add ``drive`` and ``replay`` to the ``offnominal`` parser."""
    rp = sub.add_parser(
        "replay", help="replay an MCAP recording through rtctl and compare its commands bit for bit",
        description="Feed a recording's measurements to a fresh rtctl controller (same tables and config as the "
                    "recording) and report the first command that differs (time, wheel, field) and the step times; "
                    "--hil runs the controller in its own process at the real 5 Hz clock and counts deadline misses. "
                    "The recording's provenance is checked first: other tables or configuration refuse the replay "
                    "(by name), other versions or platform warn; --rtol/--atol compare within a tolerance.")
    rp.add_argument("recording", help="an .mcap file written by offnominal drive (or a rover)")
    rp.add_argument("--tables", help="table index or folder (default: the shipped tables)")
    rp.add_argument("--config", help="rtctl controller config TOML (default: rtctl's defaults)")
    rp.add_argument("--hil", action="store_true", help="controller in its own process over a pipe, real 5 Hz clock")
    rp.add_argument("--ticks", type=int, help="with --hil: only the first N ticks")
    rp.add_argument("--csv", metavar="DIR", help="also export every channel as CSV into DIR")
    rp.add_argument("--rtol", type=float, help="tolerance mode: relative tolerance of a command (default: bit for bit)")
    rp.add_argument("--atol", type=float, help="tolerance mode: absolute tolerance of a command, m/s or rad "
                    "(default: bit for bit); the first command beyond atol + rtol * |recorded| is reported")
    rp.add_argument("--allow-mismatch", action="store_true",
                    help="replay even when the recording's tables or controller configuration differ from these "
                         "(named in a warning)")
    rp.set_defaults(func=_cmd_replay)

    dr = sub.add_parser(
        "drive", help="closed-loop drive of the simulated mini rover (failures, controllers, truth); section 7.3",
        description="Drive the simulated mini rover (Table 7.2) with a failure from a scenario file and one or "
                    "more controllers; print final/max heading and cross-track error and mean speed; write the "
                    "plot, the metrics and one MCAP recording per drive.")
    dr.add_argument("scenario", nargs="?", help=f"scenario TOML or shipped name (default: {DEFAULT_SCENARIO})")
    dr.add_argument("--controllers", default="rtctl,none",
                    help="comma list of none, ff, fb, ff+fb, ff+optfb, rtctl (default: %(default)s)")
    dr.add_argument("--section-7-3", action="store_true",
                    help="run the three scenarios of section 7.3 with the dissertation's controllers")
    dr.add_argument("--with-rtctl", action="store_true", help="with --section-7-3: add rtctl to every scenario")
    dr.add_argument("--truth", help="truth TOML or shipped name (soil_soft_30, soil_stiff_30, slope_5deg, "
                    "worn_rr_tether): soil, per-wheel radius and steer offset, slope, tether")
    dr.add_argument("--mismatch", action="store_true",
                    help="also drive with truths the model lacks: soil 30%% softer and stiffer, a 5 deg slope, "
                         "pose fixes only every 10 s")
    dr.add_argument("--tables", help="table index or folder for rtctl (default: the shipped tables)")
    dr.add_argument("--config", help="rtctl controller config TOML (default: rtctl's defaults)")
    dr.add_argument("--distance", type=float, default=1.5, help="metres along the path (default: %(default)s)")
    dr.add_argument("--dt", type=float, default=0.1, help="plant step, s (default: %(default)s)")
    dr.add_argument("--seed", type=int, default=1, help="noise seed (default: %(default)s)")
    dr.add_argument("--pose-period", type=float, help="s between pose fixes (0: none; default 0.2)")
    dr.add_argument("--pose-delay", type=float, help="pose latency, s (default 0)")
    dr.add_argument("--out", default="out/drive", help="output folder (default: %(default)s)")
    dr.add_argument("--no-record", action="store_true", help="skip the MCAP recordings")
    dr.add_argument("--hil", action="store_true",
                    help="run rtctl in its own process at the real 5 Hz clock (1.5 m takes 50 s); deadline misses "
                         "are counted and a late command is replaced by the previous one")
    dr.add_argument("--quiet", action="store_true", help="no progress bar")
    dr.set_defaults(func=_cmd_drive)

"""Why has the MER-class rover no forward locked-RF primitive: actuator limits, the zero-slip
construct, or the rocker-bogie's physics? (issue 23 audit, T1a)

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_locked_forward.py [--skip-limits]

1. Solves the shipped ``offline/scenarios/rovers/mer_rf_locked.toml`` (forward, 3 cm/s) as it is and
   prints the search's evidence and the furthest point it reached (each wheel's steering, load,
   slip, F_x, M_y).
2. The zero-slip load row at that point: for each wheel, F_z of its zero-slip state
   (``omega = speed / r_s``, its own slip angle, sinkage ``h0``) minus its load, scanned over
   ``h0`` from the lower to the upper bound with everything else held: does the row change sign
   (has a root), once (monotone)? Then, for the steered front wheel, the largest zero-slip F_z the
   ``h0`` bounds allow at slip angles 0-89 deg, against the largest load bound ``W / 2``. The row
   is the sinkage that fixes theta_m0 and theta_r0 in skid (eqs. (5.3)-(5.4)); a wheel in slip
   does not use ``h0`` anywhere else.
3. The same locked-RF primitive, forward and backward, on a copy of the rover file whose rocker
   and bogie pivots are moved to the wheels' ground-contact height (wheel centres 0.13 m, one
   wheel radius, above the pivots; centre of mass kept 0.53 m above the ground): a wheel's drag
   then has no lever arm about the pivots, so the load the rocker moves onto a dragged front wheel
   (forward) or off a dragged rear wheel (backward) is gone. Same wheel model, same zero-slip
   construct, same actuator limits.
   With ``--sweep`` only: the forward case with the pivots 0.30, 0.20 and 0.10 m above the ground
   contact (shipped 0.43 m, part 3 0), the bogie pivots and the centre of mass moved with them.
4. (skipped with ``--skip-limits``) The shipped geometry with the drive speed limit raised from
   0.385 to 1.0 rad/s and the torque limit from 30 to 300 N m, RF steering free, then held
   straight.

Prints one line per case (status, objective, IPOPT runs and iterations, CPU seconds). Writes
nothing. Measured in ``results_any_rover_audit.md`` (T1a).
"""

from __future__ import annotations

import argparse
import math
import resource
import tempfile
from pathlib import Path

import numpy as np

from offline.rover.primitives import PrimitiveResult, SolverOptions, _problem_for, solve_primitive
from offline.rover.scenario import Scenario, load_scenario
from rtctl.physics.backend import NUMPY

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "rtctl" / "physics" / "rovers"


def _cpu() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_utime + resource.getrusage(resource.RUSAGE_SELF).ru_stime


def _solve(label: str, sc: Scenario, evidence: bool = False) -> PrimitiveResult:
    c0 = _cpu()
    r = solve_primitive(sc)
    print(f"{label}: {r.status} objective {r.objective:.4f} runs {r.stats['n_attempts']} iterations "
          f"{r.stats['iterations']} CPU {_cpu() - c0:.1f}", flush=True)
    if evidence and not r.ok:
        for k, v in r.evidence.items():
            print(f"  {k}: {v}")
    print("  " + ("the primitive" if r.ok else "the point returned (furthest reached)") + ":")
    for w, d in r.wheels.items():
        print(f"  {w}: steer {math.degrees(d.steer):.2f} deg load {d.load:.1f} N slip {d.slip:.3f} "
              f"Fx {d.wrench[0]:.1f} N My {d.wrench[4]:.2f} N m h {1e3 * d.sinkage:.2f} mm h0 {1e3 * d.sinkage_zero_slip:.2f} mm")
    return r


def zero_slip_rows(sc: Scenario, r: PrimitiveResult) -> None:
    """Part 2 (module docstring)."""
    pb = _problem_for(sc, SolverOptions())

    def fz0(k: str, beta: float, h0: np.ndarray) -> np.ndarray:
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, beta)
        m = pb.model_of[k]
        return np.array([float(np.asarray(m.wrench(vx, vy, sc.speed / pb.rs_of[k], h, h).Fz).ravel()[0]) for h in h0])

    print("zero-slip load row F_z0(h0) - W at the point above, h0 over its bounds (400 values), everything else held:")
    for k, d in r.wheels.items():
        wb = pb.wheel_bounds(sc, k)
        hs = np.linspace(wb.lo["h0"], wb.hi["h0"], 400)
        f = fz0(k, d.steer, hs) - d.load
        roots = np.where(np.diff(np.sign(f)) != 0)[0]
        print(f"  {k}: slip angle {math.degrees(d.steer):.2f} deg, W {d.load:.1f} N: from {f[0]:.1f} to {f[-1]:.1f} N, "
              f"monotone {bool(np.all(np.diff(f) > 0))}, sign changes {len(roots)} (h0 {', '.join(f'{1e3 * hs[i]:.2f}' for i in roots)} mm; "
              f"the point's {1e3 * d.sinkage_zero_slip:.2f} mm)")
    k = "LF"
    wb = pb.wheel_bounds(sc, k)
    hs = np.linspace(wb.lo["h0"], wb.hi["h0"], 400)
    print(f"  {k}: largest zero-slip F_z within the h0 bounds [{1e3 * wb.lo['h0']:.0f}, {1e3 * wb.hi['h0']:.0f}] mm, against "
          f"the load bound W / 2 = {wb.hi['W']:.1f} N:")
    for bdeg in (0.0, 15.0, 28.5, 45.0, 60.0, 75.0, 85.0, 89.0):
        f = fz0(k, math.radians(bdeg), hs)
        print(f"    slip angle {bdeg:4.1f} deg: F_z0 from {f[0]:.1f} N to max {f.max():.1f} N (at h0 {1e3 * hs[f.argmax()]:.1f} mm), "
              f"monotone {bool(np.all(np.diff(f) > 0))}")


def _with_lever(text: str, lever: float) -> str:
    """The rover file with the rocker pivots ``lever`` m above the wheels' ground contact (the
    shipped file: 0.43 m, wheel centres 0.30 m below the pivots, radius 0.13 m), the bogie pivots
    at the same fraction of it above the ground (shipped 0.28 / 0.43) and the centre of mass kept
    0.53 m above the ground; nothing else changes."""
    zw = 0.13 - lever  # wheel centres relative to the rocker pivot axis
    zb = zw - 0.13 + lever * 0.28 / 0.43  # bogie pivots
    out = (text.replace("-0.30]", f"{zw:.4f}]").replace("pivot_m = [-0.325, -0.6, -0.15]", f"pivot_m = [-0.325, -0.6, {zb:.4f}]")
           .replace("pivot_m = [-0.325, 0.6, -0.15]", f"pivot_m = [-0.325, 0.6, {zb:.4f}]")
           .replace("centre_of_mass_m = [0.0, 0.0, 0.10]", f"centre_of_mass_m = [0.0, 0.0, {0.53 - lever:.4f}]"))
    if out.count(f"{zw:.4f}]") < 6 or out.count(f"{zb:.4f}]") < 2 or f"{0.53 - lever:.4f}]" not in out:
        raise RuntimeError("mer_class_rocker_bogie.toml: the geometry changed; update the bench's copy")
    return out


def low_pivots(tmp: Path, levers: tuple[float, ...] = (0.0,), directions: tuple[str, ...] = ("forward", "backward")) -> None:
    """Part 3 (module docstring); ``levers`` other than 0: the sweep of ``--sweep``."""
    text = (SRC / "mer_class_rocker_bogie.toml").read_text()
    for lever in levers:
        (tmp / "mer_low.toml").write_text(_with_lever(text, lever))
        for direction in directions:
            p = tmp / f"low_{direction}.toml"
            p.write_text('[scenario]\nname = "mer_low_pivots_rf_locked"\nrover = "mer_low.toml"\nspeed_m_s = 0.03\n'
                         + ('drive_direction = "backward"\n' if direction == "backward" else "") + '[wheels.RF]\nlocked = true\n')
            _solve(f"rocker pivots {lever:.2f} m above the ground contact (shipped 0.43), RF locked, {direction}",
                   load_scenario(p), evidence=True)


def limits(tmp: Path) -> None:
    """Part 4 (module docstring)."""
    text = (SRC / "mer_class_rocker_bogie.toml").read_text()
    if "drive_speed_max_rad_s = 0.385" not in text or "drive_torque_max_N_m = 30.0" not in text:
        raise RuntimeError("mer_class_rocker_bogie.toml: the actuator limits changed; update the bench")
    (tmp / "mer_free.toml").write_text(text.replace("drive_speed_max_rad_s = 0.385", "drive_speed_max_rad_s = 1.0")
                                       .replace("drive_torque_max_N_m = 30.0", "drive_torque_max_N_m = 300.0"))
    for steer in (None, 0.0):
        p = tmp / "s.toml"
        extra = "" if steer is None else f"steer_stuck_deg = {steer}\n"
        p.write_text('[scenario]\nname = "mer_free_rf_locked"\nrover = "mer_free.toml"\nspeed_m_s = 0.03\n'
                     '[wheels.RF]\nlocked = true\n' + extra)
        _solve(f"RF locked forward, drive limit 1.0 rad/s, torque 300 N m, steer {'free' if steer is None else steer}",
               load_scenario(p))


def main(argv: list[str] | None = None) -> int:
    """Run the parts (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip-limits", action="store_true", help="skip part 4 (the raised actuator limits, about 100 CPU-s)")
    ap.add_argument("--sweep", action="store_true",
                    help="only the lever sweep: part 3 forward with the rocker pivots 0.30, 0.20, 0.10 m above the ground contact")
    args = ap.parse_args(argv)
    if args.sweep:
        with tempfile.TemporaryDirectory() as folder:
            tmp = Path(folder)
            (tmp / "mer_class_wheel.toml").write_text((SRC / "mer_class_wheel.toml").read_text())
            low_pivots(tmp, (0.30, 0.20, 0.10), ("forward",))
        return 0
    sc = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_rf_locked.toml")
    r = _solve("mer_rf_locked as shipped", sc, evidence=True)
    zero_slip_rows(sc, r)
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        (tmp / "mer_class_wheel.toml").write_text((SRC / "mer_class_wheel.toml").read_text())
        low_pivots(tmp)
        if not args.skip_limits:
            limits(tmp)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

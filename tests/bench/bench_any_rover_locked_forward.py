"""Is the MER-class rover's forward locked-RF primitive infeasible because of its actuator limits? (issue 23 audit)

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_locked_forward.py

Solves ``mer_rf_locked`` forward at 3 cm/s on a copy of ``mer_class_rocker_bogie.toml`` whose drive
speed limit is raised from 0.385 to 1.0 rad/s and its torque limit from 30 to 300 N m, with the
right-front steering free, then held straight. Prints one line per case (status, objective, IPOPT
runs and iterations, CPU seconds) and, for an optimal one, each wheel's steering, load and slip.
First, the shipped ``offline/scenarios/rovers/mer_rf_locked.toml`` as it is, with the search's
evidence (the most violated constraint, how far the continuation from the nominal primitive got).
Writes nothing. Measured in ``results_any_rover_audit.md`` (T1a).
"""

from __future__ import annotations

import resource
import tempfile
from pathlib import Path

from offline.rover.primitives import solve_primitive
from offline.rover.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    src = ROOT / "rtctl" / "physics" / "rovers"
    text = (src / "mer_class_rocker_bogie.toml").read_text()
    if "drive_speed_max_rad_s = 0.385" not in text or "drive_torque_max_N_m = 30.0" not in text:
        raise RuntimeError("mer_class_rocker_bogie.toml: the actuator limits changed; update the bench")
    sc = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_rf_locked.toml")
    c0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime
    r = solve_primitive(sc)
    print(f"mer_rf_locked as shipped: {r.status} (CPU {resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0:.1f})")
    for k, v in r.evidence.items():
        print(f"  {k}: {v}")
    for w in sc.wheels:
        d = r.wheels.get(w)
        if d is not None:
            print(f"  {w}: steer {d.steer * 57.29578:.2f} deg load {d.load:.1f} N slip {d.slip:.3f}")
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        (tmp / "mer_class_wheel.toml").write_text((src / "mer_class_wheel.toml").read_text())
        (tmp / "mer_free.toml").write_text(text.replace("drive_speed_max_rad_s = 0.385", "drive_speed_max_rad_s = 1.0")
                                           .replace("drive_torque_max_N_m = 30.0", "drive_torque_max_N_m = 300.0"))
        for steer in (None, 0.0):
            p = tmp / "s.toml"
            extra = "" if steer is None else f"steer_stuck_deg = {steer}\n"
            p.write_text('[scenario]\nname = "mer_free_rf_locked"\nrover = "mer_free.toml"\nspeed_m_s = 0.03\n'
                         '[wheels.RF]\nlocked = true\n' + extra)
            sc = load_scenario(p)
            c0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime
            r = solve_primitive(sc)
            print(f"RF locked forward, drive limit 1.0 rad/s, torque 300 N m, steer {'free' if steer is None else steer}: "
                  f"{r.status} objective {r.objective:.4f} runs {r.stats['n_attempts']} iterations {r.stats['iterations']} "
                  f"CPU {resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0:.1f}", flush=True)
            if r.ok:
                for w in sc.wheels:
                    d = r.wheels[w]
                    print(f"  {w}: steer {d.steer * 57.29578:.2f} deg load {d.load:.1f} N slip {d.slip:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark: per-wheel actuator terms in the drive library (issue 24): what they cost and what they do.

Each case records a 40 s calibration drive (as ``bench_drive_empirical.py``: seed 3 for the
effects, :data:`~offline.discrepancy.drive.synthetic.REALISTIC_SENSORS`) once, then diagnoses it
with the whole drive tool (:func:`offline.discrepancy.drive.diagnosis.diagnose_drives`: library,
then the empirical stage when the library does not explain the drive; one process, ``workers=1``)
under several *configurations*, each in its own child process:

``main``          the code of a baseline tree (``--baseline``, e.g. a worktree of main) with its
                  default library (no per-wheel actuator terms);
``main+act``      the baseline tree with ``DRIVE_CANDIDATES_WITH_ACTUATORS`` (the old
                  ``--per-wheel-actuators``: all sixteen per-wheel terms fitted on every drive);
``new``           this tree with its default library.

CPU seconds are the child's own (``time.process_time``) plus its children's; children of one case
run at the same time (``--jobs``), so the same load falls on each. Seconds depend on the load, the
ratios much less; verdicts depend on the seeds only.

Cases: ``shortfall_RL`` (the RL wheel-speed servo reaches 80 % of its command,
``concealed_effects.WheelSpeedServoShortfall``: the same law as ``speed_shortfall_RL``),
``current_limited_RL`` (RL rim speed clipped at 0.04 m/s, ``concealed_unknowns.CurrentLimitedServo``:
the law of ``speed_saturation_RL``), ``rate_limited_RL`` (RL servo slewing at a bounded
acceleration and clipped by a back-EMF ceiling, written here: a mechanism of its own),
``noiseN`` (noise-only drive, seed N), and the in-library cases of ``bench_drive_discrepancy.py``
by a substring of their name (e.g. ``terrain_plane_3.5``).

``--screen-only`` runs this tree's diagnosis only up to its screen of the per-wheel terms (the
regions located as the engine does, with the same seed) and reports which terms it fits. Where it
fits none, the library, and every random draw after it, are those of the library without the
per-wheel terms, so the whole diagnosis is the baseline's (verdict.json identical but for the
``screening`` list and the seconds): that is how the noise-only drives and the in-library cases
are run cheaply. ``noiseA-B`` names a range of noise-only seeds.

Run (appends rows to tests/bench/results_drive_actuators.json and rewrites the .md)::

    git worktree add --detach /tmp/base main
    nice python tests/bench/bench_drive_actuators.py --baseline /tmp/base --configs main,main+act,new shortfall_RL noise31
    nice python tests/bench/bench_drive_actuators.py --screen-only noise31-50 terrain_plane_3.5 tether steering_encoder
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "tests/bench/results_drive_actuators"
DURATION = 40.0
SEED = 3


def run_one(path: str, seed: int, library: str) -> None:
    """Child: diagnose one recording with the ``offline`` on the path; print one JSON line."""
    import resource

    import offline
    import offline.discrepancy.drive.candidates as dc
    import offline.discrepancy.drive.diagnosis as dd
    from offline.rover.scenario import load_scenario

    top = Path(offline.__file__).resolve().parent
    sc = load_scenario(top / "scenarios/nominal.toml")
    kw: dict[str, Any] = {"workers": 1}
    if library == "act":
        kw["candidates"] = dc.DRIVE_CANDIDATES_WITH_ACTUATORS

    def children() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    stages: list[str] = []

    def note(m: str) -> None:  # which held-out refits ran (the progress messages say)
        if m.startswith(("held-out refits of", "no held-out refit of")):
            stages.append(m)

    t0, c0, k0 = time.perf_counter(), time.process_time(), children()
    v = dd.diagnose_drives([path], sc, seed=seed, progress=note, **kw)
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0 + children() - k0
    ch = v.chosen
    print(json.dumps({"code": str(top.parent), "seconds": secs, "cpu_seconds": cpu, "simulations": v.model.simulations,
                      "status": v.status, "named": v.missing_physics,
                      "chosen": None if ch is None else {"keys": list(ch.keys), "names": list(ch.names),
                                                         "values": list(ch.values), "units": list(ch.units)},
                      "screened": list(getattr(v, "screened", []) or []),
                      "significant": [s.label for s in v.scores if s.significant], "refits": stages,
                      "scores": [{"label": s.label, "held_out": s.delta_cv, "in_sample": v.chi2_cv_base - s.chi2_in,
                                  "refit": s.refit, "significant": s.significant} for s in v.scores],
                      "empirical": [t.law() for t in v.empirical.terms] if v.empirical is not None else None},
                     default=float))


@dataclass
class _RateLimitedServo:
    """Written here, independent of the library's terms: the ``wheel``'s speed servo slews its rim
    speed toward its target at most ``accel`` (m/s^2) times the command period per tick (its own
    state, kept between ticks), the target being the command clipped at ``v_max`` (m/s; a motor at
    its supply voltage). A rate limiter in series with a saturation: neither the library's cap
    nor its first-order lag."""

    wheel: str = "RL"
    v_max: float = 0.04
    accel: float = 0.25
    period: float = 0.2
    name: str = "rate_limited_servo"

    def make(self) -> Any:
        sys.path.insert(0, str(ROOT / "tests"))
        from concealed_effects import Effect
        from offline.sim.truth import WHEELS

        outer = self
        i = WHEELS.index(self.wheel)

        class Servo(Effect):  # type: ignore[misc]
            name = outer.name
            physics = "one wheel-speed servo: bounded acceleration and a back-EMF speed ceiling"

            def __init__(self) -> None:
                self.v = 0.0

            def actuator_path(self, c: Any) -> Any:
                target = math.copysign(min(abs(c.rim_speed[i]), outer.v_max), c.rim_speed[i])
                step = outer.accel * outer.period
                self.v += min(max(target - self.v, -step), step)
                return replace(c, rim_speed=tuple(self.v if j == i else x for j, x in enumerate(c.rim_speed)))

        return Servo()


class _Screened(Exception):
    pass


def screen_only(path: Path, seed: int) -> dict[str, Any]:
    """This tree's diagnosis (defaults) up to its screen; which per-wheel terms it fits."""
    import offline.discrepancy.drive.diagnosis as dd
    from offline.rover.scenario import load_scenario

    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    got: dict[str, Any] = {}

    def say(msg: str) -> None:
        if msg.startswith("screened terms fitted: "):
            got["fitted"] = [k for k in msg.split(": ", 1)[1].split(", ") if k != "none"]
            raise _Screened
        if msg == "locating regions":
            got["t0"] = time.process_time()

    t0 = time.process_time()
    try:
        dd.diagnose_drives([path], sc, seed=seed, progress=say, workers=1)
    except _Screened:
        pass
    return {"fitted": got["fitted"], "cpu_seconds": time.process_time() - t0}


def _record(name: str, tmp: Path) -> tuple[Path, int]:
    sys.path.insert(0, str(ROOT / "tests"))
    sys.path.insert(0, str(ROOT / "tests" / "bench"))
    from bench_drive_discrepancy import cases as library_cases
    from concealed_effects import Effect, WheelSpeedServoShortfall, record_concealed
    from concealed_unknowns import CurrentLimitedServo
    from offline.rover.scenario import load_scenario
    from offline.sim.truth import Truth

    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    f = tmp / f"{''.join(c if c.isalnum() else '_' for c in name)}.mcap"
    per_wheel = {"shortfall_RL": WheelSpeedServoShortfall, "current_limited_RL": CurrentLimitedServo,
                 "rate_limited_RL": lambda: _RateLimitedServo().make()}
    if name in per_wheel:
        return record_concealed(f, sc, per_wheel[name](), seed=SEED, duration=DURATION), SEED
    if name.startswith("noise") and name[5:].isdigit():
        seed = int(name[5:])
        return record_concealed(f, sc, Effect(), seed=seed, duration=DURATION), seed
    inl = [c for c in library_cases(Truth.nominal(sc.params, sc.rover))["effects"] if c[2] and name in c[0]]
    if not inl:
        raise SystemExit(f"no case matches {name!r}")
    _, make, _, seed = inl[0]
    return record_concealed(f, sc, make(), seed=seed, duration=DURATION), seed


def _start(code: Path, path: Path, seed: int, library: str) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(code), OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, __file__, "--run-one", str(path), str(seed), library],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())


def _result(p: subprocess.Popen[str]) -> dict[str, Any]:
    out, err = p.communicate()
    if p.returncode:
        return {"error": err[-1500:]}
    return dict(json.loads(out.strip().splitlines()[-1]))


def _md(data: dict[str, Any]) -> str:
    md = ["# Per-wheel actuator terms in the drive library: cost and effect", "",
          "`nice python tests/bench/bench_drive_actuators.py --baseline TREE --configs ... CASE ...` (module docstring). "
          "One 40 s drive per case, diagnosed by each configuration in its own process (workers=1), the configurations "
          "of a case at the same time. CPU seconds include child processes.", ""]
    md += ["| case | config | commit | CPU s | wall s | re-simulations | verdict | named | empirical | when (load) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data.get("rows", []):
        x = r["result"]
        if "error" in x:
            md.append(f"| {r['case']} | {r['config']} | `{r['commit']}` | error | | | | | | {r['when']} |")
            continue
        emp = "-" if x["empirical"] is None else ("; ".join(x["empirical"]) or "none")
        ch = x.get("chosen")
        fitted = ("" if not ch else " (" + ", ".join(f"{n} {v:.4g} {u}" for n, v, u in zip(ch["names"], ch["values"], ch["units"]))
                  + ("" if x["named"] else f"; best attempt {' + '.join(ch['keys'])}") + ")")
        md.append(f"| {r['case']} | {r['config']} | `{r['commit']}` | {x['cpu_seconds']:.0f} | {x['seconds']:.0f} | "
                  f"{x['simulations']} | {x['status']} | {' + '.join(x['named']) or '-'}{fitted} | {emp} | "
                  f"{r['when']} ({r['load']}) |")
    if data.get("screen"):
        md += ["", "## The screen alone (`--screen-only`)", "",
               "Per-wheel terms this tree's default diagnosis fits on each drive (none: the library and every draw "
               "after it are the baseline's, so the verdict is the baseline's).", "",
               "| case | seed | commit | per-wheel terms fitted | CPU s to the screen | when |", "|---|---|---|---|---|---|"]
        for r in data["screen"]:
            md.append(f"| {r['case']} | {r['seed']} | `{r['commit']}` | {', '.join(r['fitted']) or 'none'} | "
                      f"{r['cpu_seconds']:.1f} | {r['when']} |")
    return "\n".join(md) + "\n"


def main(argv: list[str]) -> int:
    if argv[:1] == ["--run-one"]:
        run_one(argv[1], int(argv[2]), argv[3])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, help="a worktree of the baseline commit (main)")
    ap.add_argument("--screen-only", action="store_true", help="this tree's screen only (module docstring)")
    ap.add_argument("--configs", default="main,main+act,new", help="comma-separated: main, main+act, new, new+act")
    ap.add_argument("--jobs", type=int, default=2, help="configurations of a case run at once")
    ap.add_argument("cases", nargs="+")
    a = ap.parse_args(argv)
    from offline.files import write_text

    def commit(p: Path) -> str:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=p, capture_output=True, text=True).stdout.strip()

    code = {"main": (a.baseline, "default"), "main+act": (a.baseline, "act"), "new": (ROOT, "default"),
            "new+act": (ROOT, "act")}
    configs = a.configs.split(",")
    jpath = RESULTS.with_suffix(".json")
    data = json.loads(jpath.read_text()) if jpath.exists() else {"rows": []}
    names: list[str] = []
    for name in a.cases:
        lo, _, hi = name[5:].partition("-")
        if name.startswith("noise") and lo.isdigit() and hi.isdigit():
            names += [f"noise{s}" for s in range(int(lo), int(hi) + 1)]
        else:
            names.append(name)
    if a.screen_only:
        rows = data.setdefault("screen", [])
        with tempfile.TemporaryDirectory() as tmpd:
            for name in names:
                path, seed = _record(name, Path(tmpd))
                res = screen_only(path, seed)
                row = {"case": name, "seed": seed, "commit": commit(ROOT), "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                       **res}
                print(json.dumps(row), flush=True)
                rows[:] = [r for r in rows if (r["case"], r["commit"]) != (name, row["commit"])] + [row]
                write_text(jpath, json.dumps(data, indent=1, default=float))
                write_text(RESULTS.with_suffix(".md"), _md(data))
        return 0
    if a.baseline is None:
        ap.error("--baseline is required (except with --screen-only)")
    with tempfile.TemporaryDirectory() as tmpd:
        for name in names:
            path, seed = _record(name, Path(tmpd))
            load = " ".join(f"{x:.1f}" for x in os.getloadavg())
            pending = list(configs)
            while pending:
                batch, pending = pending[:a.jobs], pending[a.jobs:]
                procs = {c: _start(code[c][0], path, seed, code[c][1]) for c in batch}
                for c, p in procs.items():
                    res = _result(p)
                    row = {"case": name, "config": c, "commit": commit(code[c][0]),
                           "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "load": load, "result": res}
                    print(json.dumps(row, default=float), flush=True)
                    data["rows"].append(row)
                    write_text(jpath, json.dumps(data, indent=1, default=float))
                    write_text(RESULTS.with_suffix(".md"), _md(data))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

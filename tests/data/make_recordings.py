"""Regenerate the small closed-loop recordings that tests/test_replay.py replays.

One command (from the repository root)::

    python tests/data/make_recordings.py

For each of the three section 7.3 scenarios (clean-sided trench with RR, RR rim speed capped
at half, RR steering stuck at -50 deg) it drives the simulated mini rover for ``--ticks``
control ticks (5 Hz) with the controller and writes ``tests/data/rec_<scenario>_<controller>.mcap``
(measurements, commands, diagnostics, timing and the simulator truth; recording format 2: the
trench recording's measurements carry the operator's task ``Task("trench", "RR", 0.025)``,
which selects the trench table). The controller is
rtctl on the tables in ``tests/data/tables`` (``--controller rtctl``, the default when that
folder holds an index), or the dissertation's feed-forward + PID with its "optimal" steering
controllers (``--controller ff+optfb``). The metadata records the controller, the seed and the
sha256 of every table file, so a replay knows what it must be built from.

``--import-tables FILE ...`` first copies built tables (``offnominal tables build``) into
``tests/data/tables`` and writes their index. A table from a builder older than tables commit
57f65c1 lacks the per-point ``trust_radius`` field: it gets the table-wide header values at
every point (none: 0) and a new content hash. The committed tables (schema 2) were built on
branch tables11 directly into ``tests/data/tables`` with::

    offnominal tables build offline/scenarios/nominal.toml --grid "slope=0,5;cross_slope=-5,0,5;speed=2.5,3,3.5" --out tests/data/tables
    offnominal tables build offline/scenarios/rr_steer_stuck_50.toml \
        --grid "slope=0,5;cross_slope=-5,0,5;speed=2.5,3,3.5;steer_stuck=-60,-50,-40" --out tests/data/tables
    offnominal tables build offline/scenarios/rr_speed_cap_half.toml \
        --grid "slope=0,5;cross_slope=0;speed=2.5,3,3.5;rim_speed_cap_fraction=0.4,0.5,0.6" --out tests/data/tables
    offnominal tables build offline/scenarios/rr_trench_clean.toml \
        --grid "slope=0,5;cross_slope=0;speed=2.5,3,3.5;trench_depth=20,25,30" --out tests/data/tables

Regenerate them when a change to the controller is *meant* to change its commands; the
replay test fails on any change that is not.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENARIOS = ("rr_trench_clean", "rr_speed_cap_half", "rr_steer_stuck_50")


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def import_tables(paths: list[str], folder: Path) -> list[Path]:
    """Copy built tables into ``folder`` (unbounded rows as +-BIG, see the module notes) and index them."""
    import numpy as np

    from offline.files import write_bytes
    from offline.rover.table_builder import write_index
    from rtctl import table as T
    from rtctl.layout import NlpLayout

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for src in map(Path, paths):
        header, arrays = T._read(src)
        if "trust_radius" not in arrays:
            # per-point trust radius (tables commit 57f65c1, same schema version): the table-wide
            # header values at every point (none: 0), as for tests/data/rtctl_nominal_small.npz
            names = NlpLayout.from_json(json.dumps(header["layout"])).parameter_names
            tr = header.get("trust_radius") or {}
            shape = np.asarray(arrays["status"]).shape
            vec = np.array([float(tr.get(n) or 0.0) for n in names])
            arrays["trust_radius"] = np.broadcast_to(vec, (*shape, vec.size)).copy()
        header = {k: v for k, v in header.items() if k != "content_hash"}
        target = folder / src.name
        write_bytes(target, T.table_bytes(header, arrays))
        T.load_table(target)  # the reader accepts it
        out.append(target)
    write_index(folder, out)
    return out


def main(argv: list[str] | None = None) -> int:
    from offline.sim.experiments import build_controller, run_drive, scenario_by_name
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator
    from rtctl.recording import Recorder, provenance

    tables = HERE / "tables"
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default=None,
                    help="rtctl (tables in tests/data/tables; the default when they exist) or one of none, ff, fb, "
                         "ff+fb, ff+optfb (the default otherwise)")
    ap.add_argument("--ticks", type=int, default=25, help="5 Hz ticks per recording (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--import-tables", nargs="+", metavar="TABLE", help="built table files to copy into tests/data/tables")
    args = ap.parse_args(argv)
    if args.import_tables:
        for t in import_tables(args.import_tables, tables):
            print(f"imported {t.relative_to(HERE.parent.parent)}")
    if args.controller is None:
        args.controller = "rtctl" if (tables / "index.json").exists() else "ff+optfb"
    factory = rtctl_factory(str(tables)) if args.controller == "rtctl" else None
    for name in SCENARIOS:
        sc = scenario_by_name(name)
        ctl = build_controller(args.controller, sc, rtctl_factory=factory)
        meta = {"scenario": sc.name, "controller": args.controller, "seed": args.seed, "ticks": args.ticks,
                "regenerate": "python tests/data/make_recordings.py"}
        if args.controller == "rtctl":
            meta["tables"] = {p.name: _sha(p) for p in sorted(tables.iterdir()) if p.is_file()}
        out = HERE / f"rec_{name}_{args.controller.replace('+', '_')}.mcap"
        with Recorder(out, meta, truth=True, provenance=provenance(ctl)) as rec:
            sim = RoverSimulator(sc, seed=args.seed)
            run_drive(sim, ctl, distance=1e9, max_time=0.2 * (args.ticks - 1) + 1e-9, recorder=rec)
        print(f"wrote {out.relative_to(HERE.parent.parent)} ({out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

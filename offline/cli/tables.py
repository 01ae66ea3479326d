"""Table commands: ``offnominal tables build | info | verify`` (lookup tables for the on-rover QP)."""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from .common import fail

__all__ = ["register"]

_BUILD_EPILOG = """\
Axes (SI inside; --grid takes display units): slope [deg], cross_slope [deg], speed [cm/s], and
the failure's own parameter when the scenario has one: steer_stuck [deg] (a stuck steering
wheel), rim_speed_cap_fraction [1] (a rim-speed cap, as a fraction of the travel speed),
trench_depth [mm] (a trench goal). Defaults: slope=0:25:5; cross_slope=-10,0,10; speed=2,4;
steer_stuck=-90:90:30; rim_speed_cap_fraction=0.25,0.5,0.75,1; trench_depth=20:35:5.

Example: offnominal tables build my_failure.toml --grid "slope=0:20:5;speed=3" --jobs 2 --out tables/
A folder may hold grids.toml with [grids] <file stem> = "<grid>" per table (used when --grid is not given,
also when one file of the folder is built alone) and [refine] <file stem> = {tol = 0.5, max_points = 200} (grid refinement, as --refine-tol/--max-points).

Refinement (--refine-tol X --max-points N): after the grid is solved, each axis cell is checked at
its midpoint (other axes at up to --refine-samples grid values) against a direct solve; cells off
by more than X variable scales get their midpoint inserted (largest first, the grid stays a tensor
product of at most N points), the new points are solved, and the new half-cells checked again
(--refine-rounds). The table header records every check and insertion.
An interrupted build (or refinement) resumes from <out>/.<name>.partial/ when run again with the
same options; checkpoints made by other library code are discarded with a note.
"""


def _folder_toml(folder: Path) -> dict:
    import tomllib

    from ..rover.table_builder import BuildError

    p = folder / "grids.toml"
    if not p.is_file():
        return {}
    try:
        d = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise BuildError(f"{p}: not valid TOML ({exc})") from None
    if set(d) - {"grids", "refine"}:
        raise BuildError(f"{p}: unknown table(s) {sorted(set(d) - {'grids', 'refine'})}; expected [grids] and [refine]")
    return d


def _folder_grids(folder: Path) -> dict[str, str]:
    """``[grids]`` of ``<folder>/grids.toml``: scenario file stem -> --grid text."""
    from ..rover.table_builder import BuildError

    g = _folder_toml(folder).get("grids", {})
    bad = [k for k, v in g.items() if not isinstance(v, str) or not (folder / f"{k}.toml").is_file()]
    if bad:
        raise BuildError(f"{folder / 'grids.toml'}: [grids] maps a scenario file stem to a grid string; bad entries {bad}")
    return dict(g)


def _folder_refine(folder: Path) -> dict:
    """``[refine]`` of ``<folder>/grids.toml``: scenario file stem -> RefineOptions
    (``{tol = .., max_points = .., rounds = .., samples = ..}``)."""
    from ..rover.table_builder import BuildError
    from ..rover.table_refine import RefineOptions

    out = {}
    for k, v in _folder_toml(folder).get("refine", {}).items():
        if not isinstance(v, dict) or not (folder / f"{k}.toml").is_file():
            raise BuildError(f"{folder / 'grids.toml'}: [refine] {k!r}: expected an existing scenario stem = "
                             "{tol = 0.5, max_points = 200}")
        try:
            out[k] = RefineOptions(**v)
        except TypeError as exc:
            raise BuildError(f"{folder / 'grids.toml'}: [refine] {k}: {exc}; keys are tol, max_points, rounds, samples") from None
    return out


def _world(path: str, scenario: Path) -> object:
    """The truth file ``--world`` read for one scenario (its rover and parameter set as defaults)."""
    from ..rover.scenario import ScenarioError, load_scenario
    from ..rover.table_builder import BuildError
    from ..sim.truth import TruthError, load_truth

    try:
        sc = load_scenario(scenario)
        return load_truth(path, sc.rover, sc.params)
    except (ScenarioError, TruthError) as exc:
        raise BuildError(f"--world: {exc}") from None


def _base_index(choice: str, out: Path) -> Path | None:
    """The index a fresh ``--out`` folder's index starts from (``--base-index``): None when
    ``<out>/index.json`` exists (it is updated), for ``none``, or when ``out`` is the shipped
    folder itself; ``shipped``: the shipped tables' index; else the given index file or folder."""
    if (out / "index.json").is_file() or choice == "none":
        return None
    if choice == "shipped":
        from offnominal_tables import index_path

        base = Path(index_path())
        if not base.is_file() or base.parent.resolve() == out.resolve():
            return None
        return base
    p = Path(choice)
    return p / "index.json" if p.is_dir() else p


def cmd_build(args: argparse.Namespace) -> int:
    from ..files import OutputError
    from ..rover.table_builder import BuildError, BuildOptions, build_tables, table_spec, write_index

    src = Path(args.scenario)
    files = sorted(f for f in src.glob("*.toml") if f.name != "grids.toml") if src.is_dir() else [src]
    if not files:
        return fail(f"{src}: no scenario files (*.toml) in this folder")
    if args.jobs < 1:
        return fail(f"--jobs {args.jobs}: must be >= 1")
    try:
        from ..rover.table_refine import RefineOptions

        # a single file takes its folder's grids.toml too: the shipped tables/scenarios/X.toml alone
        # builds the shipped grid of X, not the default one
        folder = src if src.is_dir() else src.parent
        grids = _folder_grids(folder)
        refines = _folder_refine(folder)
        if not src.is_dir():
            took = ([] if args.grid or src.stem not in grids else ["grid (--grid overrides)"]) + (
                ["refinement (--refine-tol/--max-points override)"] if src.stem in refines and args.refine_tol is None else [])
            if took:
                print(f"{src.stem}: {' and '.join(took)} from {folder / 'grids.toml'}")
        if (args.refine_tol is None) != (args.max_points is None):
            raise BuildError("--refine-tol and --max-points go together (e.g. --refine-tol 0.5 --max-points 200)")
        cli_refine = (RefineOptions(args.refine_tol, args.max_points, args.refine_rounds, args.refine_samples)
                      if args.refine_tol is not None else None)
        specs = []
        for f in files:
            g = args.grid if (len(files) == 1 or args.grid_all) and args.grid else grids.get(f.stem)
            specs.append(table_spec(f, g, args.family, refine=cli_refine or refines.get(f.stem),
                                    world=_world(args.world, f) if args.world else None,
                                    build=BuildOptions(schedule=args.schedule, seed_index=args.seed_index,
                                                       compile=args.compile or os.environ.get("OFFNOMINAL_COMPILE")
                                                       or "auto")))
    except BuildError as exc:
        return fail(str(exc))
    if args.world:
        files = [*files, Path(args.world)]
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        return fail(f"two scenario files share a name {sorted(n for n in names if names.count(n) > 1)}; "
                    "give each [scenario] name a distinct value")
    built = []
    t_all = time.perf_counter()

    def done(path: Path, summ: dict) -> None:
        built.append(path)
        st = ", ".join(f"{k} {v}" for k, v in summ["statuses"].items())
        print(f"{path}: {summ['grid_points']} points {summ['shape']}, {st}; feasible {summ['feasible_fraction']:.0%}; "
              f"{summ['bytes'] / 1e6:.2f} MB")
        ref = summ.get("refinement")
        if ref:
            ins = "; ".join(f"{k} +{len(v)}" for k, v in ref["inserted"].items()) or "nothing inserted"
            worst = max((c["error"] if c["error"] is not None else math.inf for c in ref["checks"]), default=0.0)
            print(f"  refinement: {ins} ({ref['stopped']}; largest checked midpoint error {worst:.3g} scales)")

    try:
        build_tables(specs, args.out, jobs=args.jobs, scheduler=args.scheduler, progress=not args.quiet,
                     keep_partial=args.keep_partial, inputs=files, on_done=done, tables_at_once=args.tables_at_once)
    except (BuildError, OutputError) as exc:
        return fail(str(exc))
    if not args.no_index:
        base = _base_index(args.base_index, Path(args.out))
        try:
            ip = write_index(args.out, built, base_index=base)
        except BuildError as exc:
            return fail(str(exc))
        n = len(json.loads(ip.read_text())["tables"])
        extra = f", with the tables of {base} (files referenced where they are)" if base is not None else ""
        print(f"index: {ip} ({n} tables{extra}); the controller finds them all with --tables {ip}")
    print(f"built {len(built)} table(s) in {time.perf_counter() - t_all:.1f} s")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from rtctl.table import STATUS_NAMES, TableError, load_table

    try:
        t = load_table(args.file)
    except TableError as exc:
        return fail(str(exc))
    h = t.header
    print(f"table {t.name}: {h.get('description', '')}")
    print(f"schema {h['schema_version']}, library {h.get('library_version')}, content hash {h['content_hash'][:16]}... (checked)")
    r = h["rover"]
    print(f"rover {r.get('name')} (weight {r.get('weight')} N, rocker {r.get('rocker_length')} m); sources: "
          + ", ".join(f"{k} {v['name']} sha256 {v['sha256'][:12]}" if isinstance(v, dict) else f"{k} {v}"
                      for k, v in h["sources"].items() if k != "scenario_text"))
    from rtctl.wheel_set import unsupported_reason, wheel_set_of

    ws = wheel_set_of(h, t.layout)
    odd = [f"{w} {'not steerable' if ws.steerable and not ws.steerable[i] else ''}"
           f"{' not driven' if ws.driven and not ws.driven[i] else ''}".strip() for i, w in enumerate(ws.wheels)]
    odd = [o for o, w in zip(odd, ws.wheels) if o != w]
    line = f"wheel set: {ws.text()}"
    if odd:
        line += "; " + ", ".join(odd)
    if ws.rover_file_sha256:
        line += f"; rover file sha256 {ws.rover_file_sha256[:12]}"
    print(line + ("; rtctl drives it" if unsupported_reason(h, t.layout) is None else "; rtctl (this version) does not drive it"))
    fam = h.get("family")
    print(f"family: {fam['kind']} of {fam['wheel']} (axis {fam['axis']})" if fam else "family: none (single scenario)")
    world = h.get("world")
    if world:
        parts = []
        if "wheel_radius_m" in world:
            parts.append("rim radius " + ", ".join(f"{w} {1e3 * r:.2f} mm" for w, r in zip(world["order"], world["wheel_radius_m"])))
        if "steer_offset_rad" in world:
            parts.append("steering offset " + ", ".join(f"{w} {math.degrees(d):+.2f} deg"
                                                        for w, d in zip(world["order"], world["steer_offset_rad"])))
        if "external_force" in world:
            e = world["external_force"]
            parts.append(f"external pull Fx {e['fx_N']:+.3g} N, Fy {e['fy_N']:+.3g} N, Mz {e['mz_Nm']:+.3g} N m")
        if "hub_contact" in world:
            hc = world["hub_contact"]
            parts.append(f"hub contact clearance {1e3 * hc['clearance_m']:.2f} mm, face width {1e3 * hc['face_width_m']:.2f} mm, "
                         f"arm {1e3 * hc['arm_m']:.2f} mm")
        print("world terms: " + "; ".join(parts))
    for k, v in t.axes.items():
        a = h["axes"][k]
        disp = [round(float(x) / a["display_factor"], 6) for x in v]
        print(f"  axis {k:<24} [{a['display_unit']}] {disp}")
    counts = {s: int((t.status == i).sum()) for i, s in enumerate(STATUS_NAMES) if (t.status == i).any()}
    print(f"grid {t.shape} = {t.feasible.size} points: " + ", ".join(f"{k} {v}" for k, v in counts.items())
          + f"; feasible {t.feasible_fraction:.0%}")
    for k, rng in t.feasible_ranges().items():
        f = h["axes"][k]["display_factor"]
        print(f"  feasible {k}: " + (f"{rng[0] / f:.4g} .. {rng[1] / f:.4g} {h['axes'][k]['display_unit']}" if rng else "none"))
    tr = h.get("trust_radius", {})
    print("trust radius (SI), smallest over the feasible points: "
          + ", ".join(f"{k} {v:.3g}" if v is not None else f"{k} -" for k, v in tr.items()))
    if t.feasible.any():
        med = np.median(t.arrays["trust_radius"][t.feasible], axis=0)
        print("trust radius (SI), median: " + ", ".join(f"{k} {med[t.layout.index(k)]:.3g}" for k in tr))
        unv = h.get("trust_unverified_points", {})
        if any(unv.values()):
            print("points whose trust radius is the unverified fallback (no re-solve succeeded): "
                  + ", ".join(f"{k} {v}" for k, v in unv.items() if v))
    ref = h.get("refinement")
    if ref:
        ins = "; ".join(f"{k}: " + ", ".join(f"{v / h['axes'][k]['display_factor']:.4g}" for v in vals)
                        for k, vals in ref["inserted"].items()) or "nothing"
        print(f"refinement (tol {ref['tolerance_per_scale']} scales, <= {ref['max_points']} points): inserted {ins}; "
              f"{ref['stopped']}")
    ev = h.get("evidence", {})
    for flat in list(ev)[: args.evidence]:
        idx = tuple(int(i) for i in np.unravel_index(int(flat), t.shape))
        op = {k: round(v / h["axes"][k]["display_factor"], 4) for k, v in t.grid_point(idx).items()}
        print(f"  {t.status_at(idx)} at {op}: {json.dumps(ev[flat])[:300]}")
    if len(ev) > args.evidence:
        print(f"  ... {len(ev) - args.evidence} more points without a primitive (--evidence N to list them)")
    return 0


def cmd_verify(args: argparse.Namespace) -> int:
    from rtctl.table import TableError

    from ..rover.table_verify import verify_table

    try:
        rep = verify_table(args.file, points=args.points, seed=args.seed, ladder=not args.no_ladder)
    except TableError as exc:
        return fail(str(exc))
    print(rep.text())
    return 0 if rep.passed else 1


def cmd_upgrade(args: argparse.Namespace) -> int:
    from rtctl.table import TableError

    from ..files import OutputError
    from ..rover.table_builder import BuildError, upgrade_table, write_index

    done = []
    try:
        for f in args.files:
            done.append(upgrade_table(f, args.out))
            print(f"{done[-1]}: schema 2 (hess_lag_xp computed at every feasible point; schema-1 trust radius kept)")
    except (TableError, BuildError, OutputError) as exc:
        return fail(str(exc))
    if not args.no_index:
        print(f"index: {write_index(args.out, done)}")
    return 0


def cmd_describe(args: argparse.Namespace) -> int:
    from rtctl.table import TableError

    from ..files import OutputError
    from ..rover.table_builder import BuildError, describe_table, write_index

    done = []
    try:
        for f in args.files:
            done.append(describe_table(f, args.out))
            print(f"{done[-1]}: failure description added (failure_kinds, failures, task, family.declares); "
                  "arrays unchanged")
    except (TableError, BuildError, OutputError) as exc:
        return fail(str(exc))
    if not args.no_index:
        print(f"index: {write_index(args.out, done)}")
    return 0


def cmd_mirror(args: argparse.Namespace) -> int:
    from rtctl.mirror import MirrorError, mirror_table
    from rtctl.table import TableError, load_table, table_bytes

    from ..files import OutputError, check_output_dir, write_bytes
    from ..rover.table_builder import BuildError, write_index

    done = []
    try:
        tables = [load_table(f) for f in args.files]
        mirrors = [mirror_table(t) for t in tables]
        out = check_output_dir(args.out, args.files, [f"{m.name}.npz" for m in mirrors])
        for m in mirrors:
            head = {k: v for k, v in m.header.items() if k != "content_hash"}
            done.append(write_bytes(out / f"{m.name}.npz", table_bytes(head, m.arrays)))
            of = m.header["mirror_of"]["name"]
            print(f"{done[-1]}: left-right mirror of {of} ({int(m.feasible.sum())}/{m.feasible.size} points with a "
                  "primitive; no solve: checked in tests/test_rtctl_mirror.py and tests/bench/bench_mirror.py)")
    except (TableError, MirrorError, OutputError, BuildError, OSError) as exc:
        return fail(str(exc))
    if not args.no_index:
        print(f"index: {write_index(args.out, done)}")
    return 0



def _files_to_folder(p: argparse.ArgumentParser, what: str) -> None:
    """The arguments of a command that writes new table files beside the inputs' (never over them)."""
    p.add_argument("files", nargs="+", help=what)
    p.add_argument("--out", required=True, help="output folder (not the folder of the inputs)")
    p.add_argument("--no-index", action="store_true", help="do not update <out>/index.json")

def register(sub: argparse._SubParsersAction) -> None:
    """Add ``tables build|upgrade|describe|mirror|info|verify``."""
    p = sub.add_parser("tables", help="build, inspect and verify lookup tables for the on-rover QP",
                       description="Lookup tables: driving primitives and the QP's data over slope, cross-slope, "
                                   "speed and the failure's parameter.")
    ts = p.add_subparsers(dest="tables_command", metavar="action")
    p.set_defaults(func=lambda a: (p.print_help(), 0)[1])

    b = ts.add_parser("build", help="build tables from scenario files", epilog=_BUILD_EPILOG,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("scenario", help="a scenario TOML file, or a folder: one table per *.toml in it")
    b.add_argument("--grid", help="axis overrides, e.g. 'slope=0:25:5;speed=2,3,4' (display units; see below)")
    b.add_argument("--grid-all", action="store_true", help="apply --grid to every file of a folder (default: single file only)")
    b.add_argument("--family", default="auto",
                   choices=("auto", "none", "steer_stuck", "rim_speed_cap_fraction", "trench_depth"),
                   help="the failure parameter to tabulate as an axis (default: from the scenario)")
    b.add_argument("--jobs", type=int, default=1, help="local worker processes (default 1)")
    b.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:8786): run there instead")
    b.add_argument("--tables-at-once", type=int, metavar="N",
                   help="with --jobs > 1 or --scheduler: build at most N of a folder's tables at the same time on the "
                        "shared workers (default: all; one table's dependent waves alone leave most of a cluster idle)")
    b.add_argument("--out", required=True, help="output folder (tables and index.json)")
    b.add_argument("--world", metavar="TRUTH.toml",
                   help="a truth file (e.g. the discrepancy tool's accepted_truth.toml) whose terms every table takes: "
                        "soil, slope / cross-slope added, tether_force_N, [tether_anchor], per-wheel radius_mm and "
                        "steer_offset_deg, [hub_contact] (recorded in the table header's 'world' and sources)")
    b.add_argument("--refine-tol", type=float, metavar="X",
                   help="refine the grid: insert the midpoint of every axis cell whose midpoint error exceeds X "
                        "variable scales (needs --max-points)")
    b.add_argument("--max-points", type=int, metavar="N", help="grid-point budget of the refined table")
    b.add_argument("--refine-rounds", type=int, default=2, help="refinement rounds (default 2)")
    b.add_argument("--refine-samples", type=int, default=3,
                   help="combinations of the other axes checked per cell (default 3)")
    b.add_argument("--schedule", choices=("continuation", "chains"), default="continuation",
                   help="continuation (default): easiest points first from a seed table's primitives, along the "
                        "failure's axis, other speeds by the exact speed scaling, the full search only for the rest; "
                        "chains: the former schedule (chains along the slope axis, every speed searched)")
    b.add_argument("--seed-index", default="shipped", metavar="shipped|none|run|INDEX",
                   help="index whose failure-free tables of the same rover, parameters and world seed the "
                        "continuation (default: the shipped index); run: the failure-free tables of this "
                        "command, built first (a folder rebuilt from scratch without reading the files it replaces)")
    b.add_argument("--compile", choices=("auto", "on", "off"), default=None,
                   help="IPOPT evaluates the NLP as C compiled once per NLP structure and cached in "
                        "$XDG_CACHE_HOME/offnominal (on), in casadi's virtual machine (off), or compiled when a C "
                        "compiler is found (auto; an NLP structure with fewer than 64 grid points over this "
                        "command's tables compiles nothing and uses a library only if it is cached); default auto, or $OFFNOMINAL_COMPILE. Compiled, the NLP is built "
                        "per wheel (SolverOptions.nlp_structure auto): README's worked example in about 0.6 of the CPU "
                        "of the virtual machine, the compilation paid once per machine and NLP (about 90 CPU s)")
    b.add_argument("--keep-partial", action="store_true", help="keep the checkpoint folder after a finished build")
    b.add_argument("--no-index", action="store_true", help="do not update <out>/index.json")
    b.add_argument("--base-index", default="shipped", metavar="shipped|none|INDEX",
                   help="when <out> has no index.json yet, start it from this index (default: the shipped "
                        "tables'), so 'offnominal drive --tables <out>' finds the new table(s) and those; the "
                        "base tables stay where they are (referenced by relative path, checked by hash)")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.set_defaults(func=cmd_build)

    u = ts.add_parser("upgrade", help="upgrade schema-1 table files to schema 2 without re-solving",
                      description="Adds hess_lag_xp (exact, from the stored primitive and multipliers) and "
                                  "trust_unverified; keeps the schema-1 trust radius (0 -> the fallback, flagged). "
                                  "A fresh 'tables build' gives the schema-2 trust radius and neighbour pass.")
    _files_to_folder(u, "schema-1 .npz tables")
    u.set_defaults(func=cmd_upgrade)

    d = ts.add_parser("describe", help="add the rover's failure description to tables built before it",
                      description="Writes, from the table's own scenario, the failure kinds the optimizer knows "
                                  "(failure_kinds: what each constrains, as data rtctl reads), the table's failures and "
                                  "task, and which declared value its family axis follows; no solve, arrays unchanged. "
                                  "rtctl does not use a failure table without it.")
    _files_to_folder(d, ".npz tables")
    d.set_defaults(func=cmd_describe)

    m = ts.add_parser("mirror", help="write the left-right mirror of tables (a rear-right table serves rear-left)",
                      description="Mirror image of each table (rtctl.mirror: right and left wheels swapped, every lateral "
                                  "quantity's sign flipped) without a solve; rtctl also does this itself at start-up for a "
                                  "failure no loaded table serves. Trench tables are refused.")
    _files_to_folder(m, ".npz tables")
    m.set_defaults(func=cmd_mirror)

    i = ts.add_parser("info", help="describe a table file (checks its hash)")
    i.add_argument("file")
    i.add_argument("--evidence", type=int, default=5, help="points without a primitive to list (default 5)")
    i.set_defaults(func=cmd_info)

    v = ts.add_parser("verify", help="check Jacobians, linearisation, interpolation and the online step against the model",
                      description="Four checks (Jacobians vs difference quotients, the first-order prediction at each "
                                  "sampled point's trust radius vs a re-solve, a primitive at sampled cell centres -- the "
                                  "raw interpolation distance there is printed, not gated since issue 22 --, and rtctl's "
                                  "online step from the interpolated primitive, 5 ticks at those centres, vs the optimum "
                                  "there); PASSED only if every gated part passed. Tolerances and why: "
                                  "offline/rover/table_verify.py. Exit code 0 passed, 1 failed.")
    v.add_argument("file")
    v.add_argument("--points", type=int, default=3, help="sampled points per check (default 3)")
    v.add_argument("--seed", type=int, default=0)
    v.add_argument("--no-ladder", action="store_true",
                   help="skip the informational linearisation step ladder (not gated; most of the time)")
    v.set_defaults(func=cmd_verify)

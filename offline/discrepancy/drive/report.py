"""Rendering a drive verdict: the engine's report folder plus the drive's plots and truth file.

:func:`~offline.discrepancy.drive.diagnosis.diagnose_drives` returns the verdict and writes
nothing; :func:`write_drive_report` renders it (matplotlib is imported only when a report is
written).
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ...files import atomic_path, write_text
from ..engine import Verdict
from ..report import write_report
from .candidates import PER_WHEEL_ACTUATOR_KEYS, TABLE_BUILDER_TAKES, RoverExtension, rover_terms, truth_from_terms, write_truth_toml
from .diagnosis import DriveModel, DriveRecording, accepted_extension
from .empirical import truth_entries

__all__ = ["write_drive_report", "params_reference"]

BELIEVED_PARAMS = "believed_params.toml"
"""The believed parameter set written beside ``accepted_truth.toml`` when no preset or file names it
(:func:`params_reference`)."""


def _scenario_params_ref(scenario: Any) -> tuple[str, Path | None]:
    """The believed scenario's own parameter reference and the folder a file reference is relative to:
    its ``[scenario] params``; else a rover file's wheels' one set (``params`` of its wheels, beside
    the rover file); else the mini rover's default ``dissertation-ch7`` (:func:`offline.rover.scenario.load_scenario`)."""
    src = Path(str(getattr(scenario, "source", "") or ""))
    try:
        vals = tomllib.loads(src.read_text()).get("scenario", {}) if src.is_file() else {}
    except (OSError, tomllib.TOMLDecodeError):
        vals = {}
    if isinstance(vals.get("params"), str):
        return vals["params"], src.parent
    rf = getattr(scenario, "rover_file", None)
    if rf is not None:
        refs = {rf.wheel_params(w) for w in rf.wheel_names}
        if len(refs) == 1:
            return next(iter(refs)), Path(rf.path).parent if rf.path else None
        return "", None
    return "dissertation-ch7", None


def _load_ref(ref: str, base: Path | None) -> tuple[Any, Path | None]:
    """The parameter set a reference names and its file (None for a built-in preset); (None, None)
    when it names none."""
    from ...physics.params import ParameterError, load_toml
    from ...rover.scenario import PARAM_PRESETS, param_preset_file

    if not ref:
        return None, None
    if ref in PARAM_PRESETS:
        return PARAM_PRESETS[ref], None
    f = param_preset_file(ref) or (Path(ref) if Path(ref).is_absolute() or base is None else base / ref)
    try:
        loaded = load_toml(f)
    except (ParameterError, OSError):
        return None, None
    return loaded.get("parameter_set"), f


def params_reference(model: Any, folder: str | Path, params_file: str = "") -> str:
    """The ``[truth] params`` of an accepted truth file written into ``folder``: the believed
    parameter set (:attr:`DriveModel.params`), named so :func:`offline.sim.truth.load_truth` reads
    it back.

    Tried in turn, the first whose set equals the believed one is written: ``params_file`` (a
    preset name or a file path, as given on the command line), then the believed scenario's own
    reference (``[scenario] params``; for a rover file without it, its wheels' parameter file,
    e.g. ``mer_class_wheel.toml`` beside the MER-class file; else ``dissertation-ch7``). A
    built-in preset is written by name; a file as its path relative to ``folder`` (the truth
    format resolves it from the truth file's folder). When none matches (a scenario's grouser
    overrides, a parameter file not found), the believed set itself is written to
    :data:`BELIEVED_PARAMS` in ``folder`` and named.

    Parameters
    ----------
    model : DriveModel
        The believed model (its ``params`` and ``scenario``).
    folder : str or Path
        Where the truth file goes.
    params_file : str
        The parameter file or preset the diagnosis was told (empty: none).
    """
    from ...physics.params import save_toml

    out = Path(folder)
    tries: list[tuple[str, Path | None]] = [(params_file, Path.cwd())] if params_file else []
    tries.append(_scenario_params_ref(model.scenario))
    for ref, base in tries:
        ps, f = _load_ref(ref, base)
        if ps is None or ps != model.params:
            continue
        if f is None:
            return ref
        from ...rover.scenario import param_preset_file

        if param_preset_file(ref) is not None:
            return ref  # a shipped parameter file by name (load_truth takes it as a scenario does)
        try:
            return Path(os.path.relpath(f.resolve(), out.resolve())).as_posix()
        except ValueError:  # another drive (Windows): an absolute path
            return f.resolve().as_posix()
    ps = model.params
    with atomic_path(out / BELIEVED_PARAMS) as tmp:
        save_toml(tmp, {"written_by": "offline.discrepancy.drive.report (the believed parameter set of the diagnosis)"},
                  soil=ps.soil, wheel=ps.wheel, tuning=ps.tuning)
    return BELIEVED_PARAMS


def write_drive_report(v: Verdict, folder: str | Path, params_file: str = "") -> Path:
    """Render a drive verdict: the engine's report folder (report.md, verdict.json, PNGs,
    :func:`offline.discrepancy.report.write_report`) plus, for drives: the trajectory plot,
    per-channel residuals over time before and after the explanation, the accepted terms as a
    truth file (``accepted_truth.toml``) the simulator and the table builder take, and the
    empirical terms (``empirical_terms.json``). Every file is written atomically; the folder is
    created. ``params_file``: the parameter file (or preset) the diagnosis was told, if any; the
    truth file names the believed parameter set (:func:`params_reference`: a preset, a rover file's
    wheel parameter file, or a copy beside it)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    obs: DriveRecording = v.observations
    model: DriveModel = v.model
    ext = accepted_extension(v)
    pngs = _drive_plots(v, out, ext)
    extra = ["", "## Drive plots", ""] + [f"![{p.stem}]({p.name})" for p in pngs]
    truth_file = None
    em = v.empirical
    entries: list[dict[str, Any]] = []
    if em is not None and em.terms:
        entries = truth_entries(em.terms)
    if v.chosen is not None and v.status not in ("agree", "unexplained", "ambiguous"):
        assert model.truth is not None
        truth, act, meas = truth_from_terms(model.params, model.truth, ext, model.wheels)
        header = {"verdict": v.status, "terms": v.chosen.label, "fitted": v.chosen.parameters_text(),
                  "held_out_chi2": f"{v.chi2_cv_base:.1f} -> {v.chosen.chi2_cv:.1f}",
                  "recordings": obs.source}
        terms = rover_terms(ext)
        dist = {k: terms[t] for k, t in (("hub_clearance_m", "hub_clearance"), ("hub_face_width_m", "hub_face_width"),
                                          ("hub_arm_m", "hub_arm"), ("anchor_tension_N", "anchor_tension"),
                                          ("anchor_bearing_rad", "anchor_bearing"),
                                          ("anchor_inverse_distance_per_m", "anchor_inverse_distance"),
                                          ("anchor_attach_x_m", "anchor_attach_x"),
                                          ("anchor_spring_rate_N_per_m", "anchor_spring_rate")) if t in terms} or None
        # per-wheel actuator terms: not in the truth format (ActuatorConfig has no per-wheel entries);
        # written with the sensor and actuator comments
        act = {**(act or {}), **{k: terms[k] for k in PER_WHEEL_ACTUATOR_KEYS if k in terms}} or None
        if entries:
            header["empirical_terms"] = "; ".join(t.law() for t in em.terms)
        truth_file = write_truth_toml(out / "accepted_truth.toml", params_reference(model, out, params_file), truth, model.truth,
                                      meas, act, header, dist, entries, wheels=model.wheels)
        extra += ["", "## Accepted terms as a simulator truth file", "",
                  f"`{truth_file.name}` (read by `offline.sim.truth.load_truth`; `offnominal drive --truth` takes it, "
                  f"and `offnominal tables build SCENARIO --world {truth_file.name} --out DIR` rebuilds the tables with "
                  "its terms: soil, slope, tether, anchored cable, per-wheel radius and steering offset).", "",
                  "Does the table builder take each accepted term?", ""]
        extra += [f"- `{k}`: {TABLE_BUILDER_TAKES.get(k, 'not known')}" for k in v.chosen.keys]
    elif entries:
        # the library explains nothing it would write; the empirical force and torque terms alone
        assert model.truth is not None and em is not None
        header = {"verdict": v.status, "empirical_terms": "; ".join(t.law() for t in em.terms),
                  "held_out_chi2": f"{em.chi2_cv_base:.1f} -> {em.chi2_cv_after:.1f}", "recordings": obs.source}
        truth_file = write_truth_toml(out / "accepted_truth.toml", params_reference(model, out, params_file), model.truth,
                                      model.truth, {}, None, header, None, entries, wheels=model.wheels)
    if em is not None:
        extra += ["", "## Empirical model of what the library lacks", ""] + [f"    {line}" for line in em.summary_lines()]
        if em.terms:
            write_text(out / "empirical_terms.json", json.dumps(em.to_json(), indent=2, default=float))
            extra += ["", "`empirical_terms.json` holds every term (SI). The force and torque terms are also in "
                      "`accepted_truth.toml` as `[[empirical_force]]` tables (`offline.sim.truth.load_truth` reads them; "
                      "`offnominal drive --truth` applies them as a disturbance hook, localised by the simulator's own "
                      "time and pose); speed losses and reading offsets are not part of the world a truth file describes "
                      "(the lines above say which terms were written)."]
    drive = {"recordings": [d.source for d in obs.drives], "segment_ticks": int(obs.segments[0].bounds[0, 1] - obs.segments[0].bounds[0, 0]),
                   "period_s": obs.drives[0].period, "heading_source": [d.heading_source for d in obs.drives],
                   "rover_terms": dict(rover_terms(ext)), "soil_changes": dict(ext.soil),
                   "truth_file": truth_file.name if truth_file else None, "simulations": model.simulations,
                   "table_builder_takes": ({k: TABLE_BUILDER_TAKES.get(k, "not known") for k in v.chosen.keys}
                                           if truth_file and v.chosen is not None else {})}
    return write_report(v, out, extra_md=extra, extra_json={"drive": drive}, empirical_file=False)


def _drive_plots(v: Verdict, out: Path, ext: RoverExtension) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obs: DriveRecording = v.observations
    model: DriveModel = v.model
    paths = []
    # trajectory: recorded pose and the open-loop re-simulation before / after (heading forced: the
    # positions come from integrating the predicted body velocities along the recorded heading)
    fig, ax = plt.subplots(figsize=(6.5, 6))
    for k, d in enumerate(obs.drives):
        ax.plot(d.pose[:, 0], d.pose[:, 1], "k-", lw=1.5, label="recorded pose" if k == 0 else None)
        for label, e, col in (("model as given", None, "tab:gray"), ("with the explanation", ext, "tab:red")):
            _, body, ok = model.simulate(d, e, 0.0)
            if not ok:
                continue
            h = d.pose[:, 2]
            vx = body[:, 0] * np.cos(h) - body[:, 1] * np.sin(h)
            vy = body[:, 0] * np.sin(h) + body[:, 1] * np.cos(h)
            x = d.pose[0, 0] + np.concatenate([[0], np.cumsum(vx[1:] * d.period)])
            y = d.pose[0, 1] + np.concatenate([[0], np.cumsum(vy[1:] * d.period)])
            ax.plot(x, y, "--", color=col, lw=1, label=f"{label} (dead reckoning)" if k == 0 else None)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("trajectory: recorded vs re-simulated")
    paths.append(_save_png(fig, out / "trajectory.png", 100))
    chans = obs.channels
    ncol = 4
    nrow = int(math.ceil(len(chans) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.6 * nrow), squeeze=False, sharex=True)
    tt = obs.features["time_s"]
    for j, ch in enumerate(chans):
        ax = axes[j // ncol, j % ncol]
        ax.axhspan(-2, 2, color="0.9")
        for label, res, mk in (("before", v.residual_before, "o"), ("after", v.residual_after, ".")):
            zz = res[ch] / obs.noise[ch]
            for k in np.unique(obs.drive):
                r = obs.drive == k
                ax.plot(tt[r], np.clip(zz[r], -30, 30), mk + "-", ms=3, lw=0.6,
                        color="tab:gray" if label == "before" else "tab:red", label=label if k == 0 else None)
        ax.set_title(f"{ch} residual / noise", fontsize=9)
        ax.grid(alpha=0.3)
    for j in range(len(chans), nrow * ncol):
        axes[j // ncol, j % ncol].axis("off")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("per-channel residuals over time (segment means, in noise units, clipped at ±30; band ±2)")
    fig.tight_layout()
    paths.append(_save_png(fig, out / "residuals_over_time.png", 90))
    return paths


def _save_png(fig: Any, path: Path, dpi: int) -> Path:
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return path

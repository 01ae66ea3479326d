"""Rendering a discrepancy verdict: the report folder (report.md, verdict.json, plots).

A diagnosis (:func:`offline.discrepancy.engine.diagnose`,
:func:`offline.discrepancy.drive.diagnosis.diagnose_drives`) returns a
:class:`~offline.discrepancy.engine.Verdict` and writes nothing; :func:`write_report` renders
it. Matplotlib is imported only here, when a report is written.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..files import atomic_path, write_text
from ..physics.params import save_toml
from .engine import Verdict

__all__ = ["write_report", "residual_plots"]


def write_report(v: Verdict, folder: str | Path, extra_md: Sequence[str] = (),
                 extra_json: Mapping[str, Any] | None = None, empirical_file: bool = True) -> Path:
    """Render a verdict: ``report.md``, ``verdict.json``, PNG plots and, for "parameters off",
    ``recalibrated.toml`` into ``folder`` (each file atomically; the folder is created).

    The diagnosis returns the :class:`~offline.discrepancy.engine.Verdict` and writes
    nothing; this is the one place that renders it (a drive adds its own plots and truth file
    in :func:`offline.discrepancy.drive.report.write_drive_report` through ``extra_md``, lines
    appended to report.md, and ``extra_json``, keys added to verdict.json). Accepted empirical terms
    (``v.empirical``) go to ``empirical_terms.json`` unless ``empirical_file`` is False (the drive
    writer writes its own, with the truth file)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "verdict.json", json.dumps({**v.to_json(), **dict(extra_json or {})}, indent=2, default=float))
    if v.recalibrated is not None:
        with atomic_path(out / "recalibrated.toml") as tmp:
            save_toml(tmp, {"written_by": "offline.discrepancy.report (parameters off)",
                            "recording": Path(str(v.observations.source)).name,
                            "held_out_chi2_before": v.chi2_cv_base,
                            "held_out_chi2_after": v.chosen.chi2_cv if v.chosen else v.chi2_cv_base},
                      soil=v.recalibrated.soil, wheel=v.recalibrated.wheel, tuning=v.recalibrated.tuning)
    pngs = residual_plots(v, out)
    md = ["# Discrepancy report", "", f"Recording: `{Path(str(v.observations.source)).name}`", "",
          f"Model: {v.model.describe() if hasattr(v.model, 'describe') else v.model}", "",
          "## Summary", "", "```", v.summary(), "```", "",
          "## Candidates (ranked by held-out improvement)", "",
          "| candidate | kind | parameters | held-out chi2 | improvement | p (adjusted) | significant |",
          "|---|---|---|---|---|---|---|",
          f"| (model as given) | | | {v.chi2_cv_base:.1f} | | | |"]
    for s in sorted(v.scores, key=lambda s: -s.delta_cv):
        padj = f"{s.p_adjusted:.3g}" if math.isfinite(s.p_adjusted) else "(extra term test)"
        md.append(f"| {s.label} | {'/'.join(s.kinds)} | {s.parameters_text()} | {s.chi2_cv:.1f} | {s.delta_cv:.1f} | "
                  f"{padj} | {'yes' if s.significant else ''} |")
    if v.status == "ambiguous":
        md += ["", "## Not identifiable from this recording", "",
               "Nothing is named. These explanations fit the held-out rows equally, or the best-scoring one has a term "
               "the data do not determine:", ""]
        md += [f"- `{s.label}`: {s.parameters_text()} (held-out chi2 {s.chi2_cv:.1f})" for s in v.explanations]
        md += ["", v.ambiguity]
    md += ["", "## Decision criterion", "", v.criterion, ""]
    if v.regions_after:
        md += ["## Regions still significant after the explanation", ""] + [f"- {r.describe()}" for r in v.regions_after] + [""]
    em = v.empirical
    if empirical_file and em is not None:
        md += ["## Empirical model of what the library lacks", ""] + [f"    {line}" for line in em.summary_lines()] + [""]
        if em.terms:
            write_text(out / "empirical_terms.json", json.dumps(em.to_json(), indent=2, default=float))
            md += ["`empirical_terms.json` holds every accepted term (SI), its law, localisation and the experiment "
                   "that would confirm its physics.", ""]
    md += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in pngs] + list(extra_md)
    write_text(out / "report.md", "\n".join(md) + "\n")
    return out


def residual_plots(v: Verdict, out: Path) -> list[Path]:
    """``residual_map.png`` (residual / noise over the first two features, before and after the
    explanation) and ``measured_vs_predicted.png``, written atomically into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obs = v.observations
    chans = obs.channels
    fx, fy = list(obs.features)[:2]
    paths = []
    fig, axes = plt.subplots(2, len(chans), figsize=(4.3 * len(chans), 7), sharex=True, sharey="row", squeeze=False)
    sc = None
    for j, ch in enumerate(chans):
        for i, (label, res) in enumerate((("before", v.residual_before), ("after", v.residual_after))):
            ax = axes[i, j]
            zz = res[ch] / obs.noise[ch]
            sc = ax.scatter(obs.features[fx], obs.features[fy], c=np.clip(zz, -10, 10), cmap="RdBu_r",
                            vmin=-10, vmax=10, s=40, edgecolors="k", linewidths=0.3)
            bad = ~np.isfinite(zz)
            ax.scatter(obs.features[fx][bad], obs.features[fy][bad], marker="x", c="k", s=30)
            ax.set_title(f"{ch} residual / noise, {label}")
            if i == 1:
                ax.set_xlabel(fx)
            if j == 0:
                ax.set_ylabel(fy)
    if sc is not None:
        fig.colorbar(sc, ax=axes, label="(measured - predicted) / noise (clipped at ±10; x: model failed)")
    p = out / "residual_map.png"
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    paths.append(p)
    fig, axes = plt.subplots(1, len(chans), figsize=(4.3 * len(chans), 4.2), squeeze=False)
    for j, ch in enumerate(chans):
        ax = axes[0, j]
        k = obs.scale_out[ch]
        m = obs.measured[ch] * k
        ax.plot(m, v.pred_before[ch] * k, "o", mfc="none", color="tab:gray", label="model as given")
        ax.plot(m, v.pred_after[ch] * k, ".", color="tab:red", label="with the explanation")
        lim = [np.nanmin(m), np.nanmax(m)]
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.set_xlabel(f"measured {ch} [{obs.units[ch]}]")
        ax.set_ylabel(f"predicted {ch} [{obs.units[ch]}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    p = out / "measured_vs_predicted.png"
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    paths.append(p)
    return paths

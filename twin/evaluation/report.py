"""Reports of a campaign: the comparison table (ours beside the paper's targets), figures, results.json.

The paper's numbers come only from the targets file (:mod:`twin.evaluation.targets`) and are printed in
their own rows marked ``paper``; nothing here copies them into a result.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..benchio import atomic_write_text
from ..units import MM_PER_M
from .targets import scored_value, target_value

__all__ = [
    "RESULTS_SCHEMA_VERSION",
    "write_results",
    "comparison_rows",
    "render_table",
    "plot_figure10",
    "plot_figure11",
    "paper_parameter_value",
    "paper_parameter_path",
    "render_parameter_table",
    "clean_json",
    "pyplot",
    "save_figure",
]

RESULTS_SCHEMA_VERSION = 1
METHOD_LABELS = {
    "distance": "distance constraint",
    "full_pose": "full-pose constraint",
    "separation": "separation (paper's method, our variant)",
    "separation_paper": "separation, paper-literal (d2 held, nominal tool, given base rotation)",
    "default": "our default estimator",
}


def clean_json(x: Any) -> Any:
    """JSON-safe: numpy to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return clean_json(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, Path):
        return str(x)
    return x


def write_results(path: str | os.PathLike, results: Mapping[str, Any]) -> Path:
    """Write ``results.json`` atomically (``schema_version`` first; ``docs/formats.md``)."""
    p = Path(path)
    body = {"schema_version": RESULTS_SCHEMA_VERSION, **clean_json(dict(results))}
    atomic_write_text(p, json.dumps(body, indent=1, sort_keys=False) + "\n")
    return p


def _g(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, Mapping) or k not in d or d[k] is None:
            return None
        d = d[k]
    return d


def comparison_rows(summaries: Mapping[str, Mapping[str, Any]], targets: Mapping[str, Any] | None,
                    *, paper_key: tuple[str, str, str] = ("simulation", "figure10", "figure10"),
                    source: str = "measured") -> list[dict[str, Any]]:
    """Rows of the comparison table: one per method (ours) and the paper's row under the separation method.

    Each row: ``label``, then for ``angle_deg`` and ``position_mm``: before/after max, mean, std and the
    improvement of the mean [%]. ``paper_key`` = (section, angle figure, position figure) of the targets file.
    """
    rows = []
    for m, s in summaries.items():
        row: dict[str, Any] = {"label": METHOD_LABELS.get(m, m), "method": m, "kind": "ours"}
        for unit in ("angle_deg", "position_mm"):
            blk = _g(s, source, unit)
            row[unit] = None if blk is None else {
                "before": blk.get("before"), "after": blk.get("after"), "improvement_percent": blk.get("improvement_percent")
            }
        rows.append(row)
        if m == "separation" and targets is not None:
            sec, fa, fp = paper_key
            pa, pp = _g(targets, sec, fa, "angle_deg"), _g(targets, sec, fp, "position_mm")
            if pa is not None or pp is not None:
                prow = {"label": f"  paper (Fig. {fa[6:]}/{fp[6:]})" if fa != fp else f"  paper (Fig. {fa[6:]})",
                        "method": "paper", "kind": "paper"}
                for unit, blk in (("angle_deg", pa), ("position_mm", pp)):
                    prow[unit] = None if blk is None else {
                        "before": blk.get("before"), "after": blk.get("after"), "improvement_percent": blk.get("improvement_percent")
                    }
                rows.append(prow)
    return rows


def _fmt(x: Any, nd: int = 4) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def render_table(rows: Sequence[Mapping[str, Any]], title: str = "") -> str:
    """Plain-text table: max / mean / rms / std before -> after, improvement of the mean."""
    head = (f"{'method':<30} | {'angle [deg] max':>17} {'mean':>17} {'rms':>17} {'std':>17} {'impr.':>6} | "
            f"{'position [mm] max':>17} {'mean':>17} {'rms':>17} {'std':>17} {'impr.':>6}")
    lines = [title, head, "-" * len(head)] if title else [head, "-" * len(head)]
    for r in rows:
        cells = [f"{r['label']:<30}"]
        for unit in ("angle_deg", "position_mm"):
            blk = r.get(unit)
            parts = []
            for stat in ("max", "mean", "rms", "std"):
                b = _g(blk, "before", stat)
                a = _g(blk, "after", stat)
                parts.append(f"{_fmt(b):>7} -> {_fmt(a):<7}")
            imp = _g(blk, "improvement_percent")
            parts.append(f"{'-' if imp is None else f'{imp:5.1f}%':>6}")
            cells.append(" ".join(parts))
        lines.append(" | ".join(cells))
    lines.append("std: sample standard deviation, compared with the paper's 'mean square error' (smaller than its mean "
                 "in most figures, so not an RMS; the paper gives no RMS); improvement: of the mean.")
    return "\n".join(lines)


def paper_parameter_path(targets: Mapping[str, Any] | None, key: str) -> str | None:
    """Dotted path into the separation targets of a ``parameters`` key's paper value (its Table 3 or 5), or
    None where the paper gives none."""
    if not targets:
        return None
    t3 = _g(targets, "simulation", "table3_deg") or {}
    t5 = _g(targets, "simulation", "table5") or {}
    if key in t5:
        return f"simulation.table5.{key}"
    if key.endswith("_deg") and key[:-4] in t3:
        return f"simulation.table3_deg.{key[:-4]}"
    return None


def paper_parameter_value(targets: Mapping[str, Any] | None, key: str, *, scored_only: bool = False) -> float | None:
    """The separation paper's identified value (its Table 3 or 5) of a ``parameters`` key (``alpha2_deg``,
    ``d3_mm``, ``theta2_plus_theta3_deg`` ...), or None where the paper gives none; with ``scored_only`` also
    None where the targets file flags the value unscored (a slip or synthetic entry, :mod:`.targets`)."""
    path = paper_parameter_path(targets, key)
    if path is None:
        return None
    if scored_only:
        return scored_value(targets, path)
    return float(target_value(targets, path))


def render_parameter_table(params: Mapping[str, Mapping[str, Mapping[str, Any]]], targets: Mapping[str, Any] | None,
                           title: str = "") -> str:
    """Identified deviations next to the injected ones and the paper's (its Tables 3 and 5), deg / mm.

    ``params``: ``results['parameters']`` (method -> key -> {true, identified, estimated}). A value the method
    did not identify (unidentifiable in its setting) is marked ``*``."""
    methods = list(params)
    if not methods:
        return ""
    keys = list(params[methods[0]])
    head = f"{'parameter':<24} {'injected':>9} {'paper':>9} " + " ".join(f"{m[:11]:>11}" for m in methods)
    lines = ([title] if title else []) + [head, "-" * len(head)]
    for k in keys:
        true = params[methods[0]][k]["true"]
        paper = paper_parameter_value(targets, k)
        flagged = paper is not None and paper_parameter_value(targets, k, scored_only=True) is None
        paper_cell = "-" if paper is None else f"{paper:.4f}" + ("^" if flagged else "")
        cells = []
        for m in methods:
            e = params[m][k]
            cells.append(f"{e['identified']:>11.4f}" if e.get("estimated", True) else f"{e['identified']:>10.4f}*")
        lines.append(f"{k:<24} {true:>9.4f} {paper_cell:>9} " + " ".join(cells))
    lines.append("injected: the world's errors; paper: its identified values (Tables 3 and 5, targets); "
                 "*: not identified by that method (held, or moved only with a coupled parameter: see "
                 "calibrations/<method>.calibration.json); ^: the paper's value is flagged unscored in the targets file "
                 "(synthetic: exactly 0.95 x the preset), printed but not a target.")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# Figures (matplotlib, Agg, PNG)
# ------------------------------------------------------------------------------------------------

def pyplot():
    """matplotlib's pyplot on the Agg backend (PNG files, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(plt, fig, path: str | os.PathLike, title: str) -> Path:
    """Title, tight layout, write the PNG (creating its folder), close the figure; the path written."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def plot_figure10(path: str | os.PathLike, angle_before, angle_after, pos_before, pos_after, distances,
                  *, method_label: str = "separation", title: str = "") -> Path:
    """The paper's Figure 10 in style: (a) angle error per compensation pair before/after [deg]; (b) position
    error per distance test before/after [mm], tests grouped by commanded distance."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    ax = axes[0]
    x = np.arange(1, len(angle_before) + 1)
    ax.plot(x, angle_before, "o-", color="tab:red", label="before compensation")
    ax.plot(x, angle_after, "s-", color="tab:blue", label=f"after ({method_label})")
    ax.set_xlabel("compensation pair")
    ax.set_ylabel("angle error [deg]")
    ax.set_title("(a) angle error")
    ax.legend()
    ax.grid(alpha=0.3)
    ax = axes[1]
    x = np.arange(1, len(pos_before) + 1)
    ax.plot(x, pos_before, "o-", color="tab:red", label="before compensation")
    ax.plot(x, pos_after, "s-", color="tab:blue", label=f"after ({method_label})")
    d = np.asarray(distances, dtype=float)
    for k, dv in enumerate(np.unique(d[np.isfinite(d)])):
        idx = np.flatnonzero(d == dv) + 1
        if k % 2 == 0:
            ax.axvspan(idx.min() - 0.5, idx.max() + 0.5, color="0.92", zorder=0)
        ax.text(idx.mean(), 1.0, f"{dv * MM_PER_M:g} mm", transform=ax.get_xaxis_transform(), ha="center", va="bottom", fontsize=8)
    ax.set_xlabel("distance test")
    ax.set_ylabel("position error [mm]")
    ax.set_title("(b) position (moved-distance) error", pad=14)
    ax.legend()
    ax.grid(alpha=0.3)
    return save_figure(plt, fig, path, title)


def plot_figure11(path: str | os.PathLike, angle_after: Mapping[str, np.ndarray], pos_after: Mapping[str, np.ndarray],
                  *, title: str = "") -> Path:
    """The paper's Figure 11 in style: per method, (a) angle error and (b) position error after compensation."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    markers = {"distance": "^-", "full_pose": "s-", "separation": "o-", "separation_paper": "v-", "default": "d--"}
    for ax, data, ylabel, name in ((axes[0], angle_after, "angle error [deg]", "(a) angle error after compensation"),
                                   (axes[1], pos_after, "position error [mm]", "(b) position error after compensation")):
        for m, v in data.items():
            ax.plot(np.arange(1, len(v) + 1), v, markers.get(m, "x-"), label=METHOD_LABELS.get(m, m), markersize=4)
        ax.set_ylabel(ylabel)
        ax.set_xlabel("compensation pair" if ax is axes[0] else "distance test")
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(plt, fig, path, title)

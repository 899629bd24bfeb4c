"""``results/benchmark_table.md``: the side-by-side table (quoted in the README), from the ``peers`` section."""

from __future__ import annotations

__all__ = ["peers_table", "pipeline_table", "growth_table"]


def _f(x, fmt="{:.4f}") -> str:
    return "-" if x is None else fmt.format(x)


def _ratio(x) -> str:
    return "-" if x is None else f"{x:.2f}x"


def peers_table(peers: dict) -> str:
    """Markdown table of every cell of the ``peers`` section."""
    lines = [
        "| noise (1 sigma) | poses | method | pos mean [mm] | pos RMS [mm] | pos max [mm] | ori RMS [deg] "
        "| pos RMS / floor | ori RMS / floor | fit time [s] | time / ours |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cell in peers["cells"]:
        s = cell["summary"]
        head = f"| {cell['noise_label']} | {cell['n_calibration']} "
        fp = s["floor_pose"]
        lines.append(
            head + f"| *floor (reference fit from the truth, pose data)* | - | {_f(fp['position_rms_mm'])} | - "
            f"| {_f(fp['orientation_rms_deg'])} | 1.00x | 1.00x | - | - |"
        )
        lines.append(
            head + f"| *floor (position data only)* | - | {_f(s['floor_position']['position_rms_mm'])} | - | - "
            f"| {_ratio(s['floor_position']['position_rms_mm'] / fp['position_rms_mm'])} | - | - | - |"
        )
        for name, m in s["methods"].items():
            if "position_rms_mm" not in m:
                err = m["failures"][0]["error"] if m["failures"] else "no prediction"
                lines.append(head + f"| {name} | failed: {err} | | | | | | | |")
                continue
            ratio = _ratio(m["ratio_position_to_pose_floor"])
            if m["data"] == "position":
                ratio += f" ({_ratio(m['ratio_position_to_own_floor'])} of pos. floor)"
            fail = f" ({len(m['failures'])} failed)" if m["failures"] else ""
            lines.append(
                head
                + f"| {name}{fail} | {_f(m['position_mean_mm'])} | {_f(m['position_rms_mm'])} "
                f"| {_f(m['position_max_mm'])} | {_f(m.get('orientation_rms_deg'))} | {ratio} "
                f"| {_ratio(m.get('ratio_orientation_to_floor'))} | {_f(m['fit_seconds_median'], '{:.3f}')} "
                f"| {_ratio(m['time_ratio_to_ours'])} |"
            )
    return "\n".join(lines) + "\n"


def pipeline_table(pipeline: dict) -> str:
    """Markdown table of the ``pipeline`` section (seconds per stereo pair)."""
    rows = pipeline.get("per_pair_seconds", {})
    lines = ["| stage | seconds per stereo pair |", "|---|---|"]
    for k, v in rows.items():
        lines.append(f"| {k} | {_f(v, '{:.4f}')} |")
    if "ratio_to_bare_render" in pipeline:
        lines.append(f"| **whole pose / bare render** | **{pipeline['ratio_to_bare_render']:.2f}x** |")
    return "\n".join(lines) + "\n"


def growth_table(growth: dict) -> str:
    """Markdown table of the identification part of the ``growth`` section."""
    ident = growth.get("identification", {})
    lines = ["| poses | identification time [s] | peak memory [MiB] |", "|---|---|---|"]
    for row in ident.get("rows", []):
        lines.append(f"| {row['poses']} | {_f(row['seconds_median'], '{:.4f}')} | {_f(row['peak_mib'], '{:.1f}')} |")
    return "\n".join(lines) + "\n"

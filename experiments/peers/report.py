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
        nom = s["nominal"]["position_rms_mm"]
        lines.append(
            head + f"| *before calibration (nominal joints, frames registered)* | - | {_f(nom)} | - | - "
            f"| {_ratio(nom / fp['position_rms_mm'])} | - | - | - |"
        )
        for name in s.get("order", list(s["methods"])):
            m = s["methods"][name]
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
    """Markdown table of the ``pipeline`` section (median seconds per stereo pair)."""
    bare = pipeline["stages"][0]["seconds"]
    lines = ["| stage | seconds per stereo pair | / bare render |", "|---|---|---|"]
    for row in pipeline["stages"]:
        lines.append(f"| {row['stage']} | {row['seconds']:.4f} | {row['seconds'] / bare:.2f}x |")
    lines.append(
        f"\n{pipeline['poses']} poses of `{pipeline['config']}` at {pipeline['image_size_px'][0]}x"
        f"{pipeline['image_size_px'][1]} px; one-off campaign preparation (world, board views, stereo calibration) "
        f"{pipeline['one_off_prepare_s']:.1f} s. Target: whole pose <= {pipeline['target_ratio']:.1f}x the bare render."
    )
    return "\n".join(lines) + "\n"


def growth_table(growth: dict) -> str:
    """Markdown tables of the ``growth`` section."""
    ident = growth["identification"]
    lines = [
        "Identification (our default estimator, 6-DOF poses):",
        "",
        "| poses | time [s] (median) | time per pose [ms] | peak traced memory [MiB] |",
        "|---|---|---|---|",
    ]
    for row in ident["rows"]:
        lines.append(
            f"| {row['poses']} | {row['seconds_median']:.4f} | {row['ms_per_pose']:.3f} | {row['peak_mib']:.1f} |"
        )
    if ident.get("loglog_slope") is not None:
        lines.append(f"\nlog-log slope of time against poses: {ident['loglog_slope']:.2f} (1 = linear).")
    camp = growth["campaign"]
    lines += [
        "",
        f"Campaign ({camp['backend']}, {camp['config']}, methods {camp['methods']}):",
        "",
        "| poses | wall time [s] | of which measuring [s] | peak RSS main [MiB] | peak RSS worker, upper bound [MiB] "
        "| RSS after imports [MiB] |",
        "|---|---|---|---|---|---|",
    ]
    for row in camp["rows"]:
        meas = row["timings_s"].get("measure_before_s", float("nan")) + row["timings_s"].get("measure_after_s", 0.0)
        lines.append(
            f"| {row['poses']} | {row['seconds']:.1f} | {meas:.1f} | {row['peak_rss_mib']:.0f} "
            f"| {row['peak_rss_largest_worker_mib']:.0f} | {row['rss_after_imports_mib']:.0f} |"
        )
    mc = growth["monte_carlo"]
    lines += [
        "",
        f"Monte-Carlo ({len(mc['seeds'])} campaigns of {mc['poses_per_campaign']} poses, {mc['backend']}):",
        "",
        "| executor | wall time [s] | campaigns per minute | distinct workers used | concurrency | load average |",
        "|---|---|---|---|---|---|",
    ]
    for row in mc["rows"]:
        lines.append(
            f"| {row['executor']} | {row['seconds']:.1f} | {row['campaigns_per_minute']:.2f} | {row['distinct_workers']} "
            f"| {row.get('concurrency', float('nan')):.2f} | {row.get('load_average_1min_at_start', float('nan')):.1f} |"
        )
    return "\n".join(lines) + "\n"

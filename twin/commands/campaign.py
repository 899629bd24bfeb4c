"""``twin campaign CONFIG --out DIR``: the runner's stages plan -> measure -> identify -> diagnose -> compensate ->
evaluate on one campaign config.

Thin: parses the arguments, runs :func:`twin.runner.campaign.run_campaign` (or ``run_repeats`` with
``--repeats``), shows progress bars, the comparison table and the diagnosis, writes results. See
``docs/runner.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HELP = "run a calibration campaign from a TOML config (experiments/*.toml): plan, measure, identify, diagnose, compensate, evaluate"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="campaign config (TOML), e.g. experiments/separation.toml")
    p.add_argument("--out", required=True, help="output folder (created; an interrupted run there resumes)")
    p.add_argument("--quick", action="store_true", help="apply the config's [quick] table (half resolution, fewer poses)")
    p.add_argument("--seed", type=int, default=None, help="override the config's seed")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: [execution] workers)")
    p.add_argument("--repeats", type=int, default=None, metavar="N",
                   help="Monte-Carlo: run N seeds (seed, seed+1, ...) in parallel and aggregate mean and spread")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster (scheduler address, e.g. tcp://10.0.0.5:8786) instead of local processes")
    p.add_argument("--mode", choices=("images", "truth_noise"), default=None,
                   help="override [measurement] mode (truth_noise: the paper's own simulation, no images)")
    p.add_argument("--no-recording", action="store_true", help="do not write the Rerun recording")
    p.add_argument("--restart", action="store_true",
                   help="discard DIR's measured poses and identifications and start again (default: resume)")


def _progress_factory(console):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    prog = Progress(TextColumn("{task.description:<30}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    TimeRemainingColumn(), console=console, transient=False)
    tasks: dict[str, int] = {}

    def update(phase: str, done: int, total: int) -> None:
        if phase not in tasks:
            tasks[phase] = prog.add_task(phase, total=total)
        prog.update(tasks[phase], completed=done, total=total)

    return prog, update


def _rich_tables(results: dict, source: str = "measured") -> list:
    """One table per quantity (angle, position): before -> after of max / mean / std, improvement of the mean."""
    from rich.table import Table

    from twin.evaluation.report import comparison_rows

    rows = comparison_rows(results["methods"], results.get("paper_targets") if source == "measured" else None,
                           paper_key=tuple(results.get("paper_key", ("simulation", "figure10", "figure10"))),
                           source=source)
    what = "measured through the instrument" if source == "measured" else "on the world's truth (no measurement noise)"
    tables = []
    for unit, title in (("angle_deg", "angle error (deg)"), ("position_mm", "moved-distance error (mm)")):
        t = Table(title=f"{results['campaign']} (seed {results['seed']}): {title}, {what}, before -> after compensation")
        t.add_column("method")
        for stat in ("max", "mean", "rms", "std"):
            t.add_column(stat, justify="right")
        t.add_column("improvement", justify="right")
        for r in rows:
            blk = r.get(unit) or {}
            cells = []
            for stat in ("max", "mean", "rms", "std"):
                b, a = (blk.get("before") or {}).get(stat), (blk.get("after") or {}).get(stat)
                cells.append("-" if b is None and a is None else
                             f"{'-' if b is None else f'{b:.4f}'} -> {'-' if a is None else f'{a:.4f}'}")
            imp = blk.get("improvement_percent")
            cells.append("-" if imp is None else f"{imp:.1f} %")
            t.add_row(r["label"], *cells, style="dim italic" if r["kind"] == "paper" else None)
        tables.append(t)
    return tables


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from twin.benchio import command_line
    from twin.runner.campaign import run_campaign, run_repeats
    from twin.runner.config import load_campaign_config, parse_campaign_config
    from twin.runner.executor import open_executor
    from twin.evaluation.report import write_results

    console = Console()
    if not console.is_terminal:
        console = Console(width=max(console.width, 120))
    cfg = load_campaign_config(args.config, quick=args.quick)
    if args.mode or args.seed is not None or args.workers:
        raw = dict(cfg.raw)
        if args.mode:
            raw["measurement"] = {**raw.get("measurement", {}), "mode": args.mode}
        if args.seed is not None:
            raw["seed"] = args.seed
        if args.workers:
            raw["execution"] = {**raw.get("execution", {}), "workers": args.workers}
        cfg = parse_campaign_config(raw, source=cfg.source, _quick_applied=cfg.quick)
    command = command_line("twin campaign", sys.argv[2:]) if len(sys.argv) > 2 else ""
    out = Path(args.out)
    if args.restart:
        import shutil

        for sub in ("work", "calibrations", "after"):
            if (out / sub).exists():
                shutil.rmtree(out / sub)
    t0 = time.perf_counter()
    prog, update = _progress_factory(console)
    if args.repeats:
        if args.repeats < 1:
            raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
        seeds = [cfg.seed + k for k in range(args.repeats)]
        kind, addr = ("dask", args.dask) if args.dask else ("process", None)
        with prog, open_executor(kind, cfg.workers, addr) as ex:
            agg = run_repeats(cfg, out, seeds, ex, progress=update)
        agg["command"] = command
        agg["config"] = cfg.raw
        write_results(out / "repeats.json", agg)
        console.print(f"{len(seeds)} seeds -> {out / 'repeats.json'}")
        st = agg["statistics"]
        for m in cfg.methods:
            parts = []
            for unit in ("angle_deg", "position_mm"):
                b = st.get(f"methods.{m}.measured.{unit}.before.mean")
                a = st.get(f"methods.{m}.measured.{unit}.after.mean")
                if a and b:
                    parts.append(f"{unit}: mean {b['mean']:.4f} -> {a['mean']:.4f} (std over seeds {a['std']:.4f})")
            if parts:
                console.print(f"  {m}: " + "; ".join(parts))
        for claim, e in agg["orderings"].items():
            console.print(f"  {claim}: holds in {e['holds']}/{e['n']} seeds")
        console.print(f"total {time.perf_counter() - t0:.1f} s")
        return 0
    if args.dask:
        with prog, open_executor("dask", cfg.workers, args.dask) as ex:
            run_ = run_campaign(cfg, out, executor=ex, progress=update, log=console.log, command=command,
                                recording=False if args.no_recording else None)
    else:
        with prog:
            run_ = run_campaign(cfg, out, progress=update, log=console.log, command=command,
                                recording=False if args.no_recording else None)
    for t in _rich_tables(run_.results):
        console.print(t)
    console.print("std = sample standard deviation: the paper's 'mean square error' is smaller than its mean in most "
                  "figures, which an RMS never is, so it is compared with our std (the paper gives no RMS); improvement "
                  "of the mean; 'paper' rows are the paper's published numbers (targets printed beside ours), not results.")
    from twin.evaluation.report import render_parameter_table

    res = run_.results
    if res["parameters"]:
        console.print(render_parameter_table(res["parameters"], res["paper_targets"] if res["paper_key"][0] == "simulation" else None,
                                             "identified parameter deviations (Tables 3 and 5 style)"), markup=False,
                      highlight=False)
    for c in run_.results["orderings"]:
        console.print(f"  paper's claim: {c['claim']}: {'holds' if c['holds'] else 'DOES NOT HOLD'} here")
    if run_.results.get("diagnosis") is not None:
        from twin.runner.outputs import diagnosis_table

        console.print(diagnosis_table(run_.results["diagnosis"]), markup=False, highlight=False)
    if run_.results["methods_unavailable"]:
        for m, why in run_.results["methods_unavailable"].items():
            console.print(f"  [yellow]method {m} not run[/yellow]: {why}")
    tm = run_.results["timings_s"]
    console.print("time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in tm.items() if v >= 0.05))
    console.print(f"results: {out / 'results.json'}; table: {out / 'table.txt'}"
                  + (f"; recording: {run_.files['recording']} (open: rerun {run_.files['recording']})" if "recording" in run_.files else ""))
    return 0

"""A campaign end to end: plan -> measure -> identify -> diagnose -> compensate -> evaluate -> report.

:func:`run_campaign` is what ``twin campaign CONFIG --out DIR`` runs: the stages of :mod:`twin.runner.stages`
in order over one :class:`~twin.runner.state.CampaignState`. :func:`run_repeats` runs it for several seeds on
an executor and aggregates the statistics. Output folder (``docs/runner.md``)::

    DIR/
      results.json            statistics per method, the paper's targets beside them, parameters, timings
      table.txt               the comparison table (and the diagnosis of the dataset when it ran)
      figure10.png            Figure 10 style (separation method: before / after)
      figure11.png            Figure 11 style (all methods after compensation)
      recording.rrd           the Rerun recording (git-ignored)
      joints.csv              the plan (JOINTS.csv format)
      dataset/                poses.csv + dataset.toml: what the estimator sees
      truth.json              what the world knew (evaluation only)
      calibrations/           one identification per method (+ the estimator's calibration.json)
      diagnosis/              twin diagnose on dataset/ ([diagnosis] enabled)
      after/<method>/         the compensated poses measured again (dataset format)
      work/                   per-pose results (resume state), renders.log; images under work/poses/images/

Resume: every measured pose is written atomically as soon as it is finished (:mod:`twin.runner.store`);
running the same command again measures only what is missing. The dataset CSV is assembled from the
per-pose files in plan order, so a resumed run writes the same bytes as an uninterrupted one. A different
config in the same folder is refused (``work/campaign.json`` holds the config's fingerprint).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..benchio import atomic_write_text
from ..evaluation.statistics import aggregate
from ..files import read_json
from .config import CampaignConfig
from .executor import SerialExecutor, open_executor, run_tasks, worker_identity
from .measure import backend_spec_for
from .methods import Identify
from .stages import MEASURING_STAGES, STAGES, visit_contexts
from .state import CampaignState, Progress, Runtime
from .store import PoseStore

__all__ = ["CampaignRun", "run_campaign", "run_repeats", "visit_contexts", "Progress", "STAGES"]


@dataclass
class CampaignRun:
    """What :func:`run_campaign` returns: the results dict (as in results.json), the table text, paths, and the
    final state of the stages."""

    out_dir: Path
    results: dict[str, Any]
    table: str
    files: dict[str, Path] = field(default_factory=dict)
    state: CampaignState | None = None


def _check_fingerprint(work: Path, cfg: CampaignConfig) -> None:
    """Refuse a folder that holds another campaign (another config or seed); mark a new one."""
    work.mkdir(parents=True, exist_ok=True)
    marker = work / "campaign.json"
    fp = cfg.fingerprint()
    if marker.exists():
        old = read_json(marker).get("fingerprint")
        if old != fp:
            raise ValueError(
                f"{work.parent} holds another campaign (fingerprint {old}, this config {fp}): "
                "use another --out folder or delete it"
            )
        return
    atomic_write_text(marker, json.dumps({"fingerprint": fp, "name": cfg.name, "seed": cfg.seed, "quick": cfg.quick}))


def run_campaign(
    cfg: CampaignConfig,
    out_dir: str | os.PathLike,
    *,
    executor: cf.Executor | None = None,
    backend_factory: str | None = None,
    implementations: Mapping[str, Identify] | None = None,
    progress: Progress | None = None,
    log: Callable[[str], None] | None = None,
    targets_path: str | os.PathLike | None = None,
    command: str = "",
    recording: bool | None = None,
    figures: bool | None = None,
) -> CampaignRun:
    """Run (or resume) the campaign ``cfg`` into ``out_dir``; returns the results and the table.

    ``executor``: where poses are measured (default: ``cfg.workers`` local processes, or in-process for one
    worker). ``backend_factory``: a ``module:callable`` measurement backend instead of ``cfg.measurement.mode``
    (tests use cheap fakes). ``implementations``: identification functions per method instead of the
    estimator's. A method the estimator does not provide is reported as unavailable, not faked.
    """
    t_start, load_start = time.perf_counter(), os.getloadavg()
    out = Path(out_dir)
    _check_fingerprint(out / "work", cfg)
    own = executor is None
    ex_ctx = (open_executor("process", cfg.workers) if cfg.workers > 1 else nullcontext(SerialExecutor())) if own \
        else nullcontext(executor)
    state = CampaignState(cfg, out)
    with ex_ctx as ex:
        rt = Runtime(ex, backend_spec_for(cfg, out / "work", backend_factory), PoseStore(out / "work" / "poses"),
                     implementations=dict(implementations or {}),
                     targets_path=None if targets_path is None else str(targets_path), progress=progress,
                     log=log or (lambda s: None), command=command, recording=recording, figures=figures,
                     load_start=tuple(load_start), t_start=t_start)
        for stage in MEASURING_STAGES:
            state = stage(state, rt)
    for stage in STAGES[len(MEASURING_STAGES):]:
        state = stage(state, rt)
    return CampaignRun(out, state.results["results"], state.results["table"], dict(state.files), state)


# ------------------------------------------------------------------------------------------------
# Monte-Carlo: several seeds on an executor
# ------------------------------------------------------------------------------------------------

def _one_seed(raw: dict, source: str | None, quick: bool, seed: int, out_dir: str, backend_factory: str | None,
              implementations: Mapping[str, Identify] | None = None) -> dict[str, Any]:
    """Worker: one whole campaign for ``seed`` (poses measured in this process), its statistics, and where it ran."""
    from .config import parse_campaign_config

    raw = {**raw, "outputs": {**raw.get("outputs", {}), "recording": False, "figures": False}}  # no images kept
    cfg = parse_campaign_config(raw, source=Path(source) if source else None, _quick_applied=quick).with_seed(seed)
    run = run_campaign(cfg, out_dir, executor=SerialExecutor(), backend_factory=backend_factory,
                       implementations=implementations, recording=False, figures=False)
    return {
        "seed": seed,
        "methods": run.results["methods"],
        "orderings": run.results["orderings"],
        "parameters": run.results["parameters"],
        "worker": worker_identity(),
        "timings_s": run.results["timings_s"],
    }


def run_repeats(
    cfg: CampaignConfig,
    out_dir: str | os.PathLike,
    seeds: Sequence[int],
    executor: cf.Executor,
    *,
    backend_factory: str | None = None,
    implementations: Mapping[str, Identify] | None = None,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the campaign once per seed (each in its own ``out_dir/seed_<n>`` folder, resumable) on
    ``executor`` and aggregate every statistic into mean and spread; ordering claims into the fraction of
    seeds where they hold."""
    out = Path(out_dir)
    items = [int(s) for s in seeds]
    done = {"n": 0}

    def on_done(_item, _res):
        done["n"] += 1
        if progress:
            progress("seeds", done["n"], len(items))

    if progress:
        progress("seeds", 0, len(items))
    per_seed = run_tasks(
        executor,
        _seed_task,
        [(cfg.raw, str(cfg.source) if cfg.source else None, cfg.quick, s, str(out / f"seed_{s}"), backend_factory,
          dict(implementations) if implementations else None) for s in items],
        on_done=on_done,
    )
    stats = aggregate([{"methods": r["methods"]} for r in per_seed])
    claims: dict[str, dict[str, Any]] = {}
    for r in per_seed:
        for c in r["orderings"]:
            e = claims.setdefault(c["claim"], {"holds": 0, "n": 0})
            e["n"] += 1
            e["holds"] += int(bool(c["holds"]))
    for e in claims.values():
        e["fraction"] = e["holds"] / e["n"] if e["n"] else float("nan")
    return {"seeds": items, "statistics": stats, "orderings": claims, "per_seed": per_seed}


def _seed_task(args: tuple) -> dict[str, Any]:
    return _one_seed(*args)

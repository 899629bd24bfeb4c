"""What the stages of a campaign hand on (:class:`CampaignState`) and what they run with (:class:`Runtime`).

Each stage of :mod:`twin.runner.stages` is a function ``stage(state, runtime) -> state``: it reads the fields
earlier stages filled and returns a copy with its own filled (``dataclasses.replace``), so a stage can be run
and tested alone from a state built by hand. The state holds the world's truth (``stations_truth``,
``true_robot``, each pose's ``truth``) only to hand it to the evaluate stage; identify, diagnose and compensate
read the dataset, the nominal model and the methods' own results.
"""

from __future__ import annotations

import concurrent.futures as cf
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..dataset import Dataset
from .config import CampaignConfig
from .measure import BackendSpec, StationTruth
from .methods import Identify, MethodResult
from .plan import CampaignPlan
from .store import PoseResult, PoseStore

__all__ = ["CampaignState", "Runtime", "Progress"]

Progress = Callable[[str, int, int], None]  # (phase, done, total)


@dataclass(frozen=True, eq=False)
class CampaignState:
    """A campaign between its stages. Filled in order by plan, measure, identify, diagnose, compensate,
    evaluate and report (each field names the stage that fills it)."""

    cfg: CampaignConfig
    out: Path
    timings: Mapping[str, float] = field(default_factory=dict)
    # plan
    plan: CampaignPlan | None = None
    # measure
    stations_nominal: Mapping[str, np.ndarray] = field(default_factory=dict)  # base2meas (4, 4) as planned
    stations_truth: Mapping[str, StationTruth] = field(default_factory=dict)  # evaluation only
    true_robot: Any = None  # evaluation only (the recording draws it)
    noise_position: float | None = None  # [m] the instrument's stated noise, when known
    before: Mapping[int, PoseResult] = field(default_factory=dict)
    dataset: Dataset | None = None
    dataset_sha256: str = ""
    measured_before: int = 0  # poses measured in this run (the rest came from the resume store)
    # identify
    methods: Mapping[str, MethodResult] = field(default_factory=dict)
    unavailable: Mapping[str, str] = field(default_factory=dict)
    # diagnose
    diagnosis: Mapping[str, Any] | None = None
    # compensate
    val_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    q_comp: Mapping[str, np.ndarray] = field(default_factory=dict)
    not_converged: Mapping[str, list] = field(default_factory=dict)
    after: Mapping[str, Mapping[int, PoseResult]] = field(default_factory=dict)
    measured_after: int = 0
    # evaluate
    evaluation: Mapping[str, Any] = field(default_factory=dict)  # method -> MethodEvaluation
    results: Mapping[str, Any] = field(default_factory=dict)  # summaries, parameters, orderings, targets
    tables: tuple[str, ...] = ()
    # report
    files: Mapping[str, Path] = field(default_factory=dict)

    def with_timing(self, name: str, seconds: float, **changes) -> "CampaignState":
        """A copy with ``timings[name] = seconds`` and the given fields replaced."""
        from dataclasses import replace

        return replace(self, timings={**self.timings, name: float(seconds)}, **changes)


@dataclass(frozen=True, eq=False)
class Runtime:
    """What the stages run with, apart from the state: where poses are measured (``executor``, the backend
    ``spec``, the resume ``store``), identification functions per method instead of the estimator's
    (``implementations``), the paper's targets file, progress and log callbacks, the command line (for
    results.json) and the recording / figures switches (``None``: the config's)."""

    executor: cf.Executor
    spec: BackendSpec
    store: PoseStore
    implementations: Mapping[str, Identify] = field(default_factory=dict)
    targets_path: str | None = None
    progress: Progress | None = None
    log: Callable[[str], None] = lambda s: None
    command: str = ""
    recording: bool | None = None
    figures: bool | None = None
    load_start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    t_start: float = 0.0  # time.perf_counter() when the run started

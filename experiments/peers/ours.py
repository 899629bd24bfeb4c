"""Our calibrators as methods of the grid: the default estimator and the papers' LM, C-LM and separation
(``twin.estimator.calibrate``), each on the same :class:`twin.dataset.Dataset` built from the split
(:func:`experiments.peers.synthetic.to_dataset`: nominal robot, no base2meas, measured poses, the noise level
in ``[noise]``). The papers' methods run as published (their defaults: unweighted SI residuals), which is what
they are benchmarked as; one extra row runs LM with ``weighting="noise"`` and ``accept="improve"`` to show what
the weights change (with the paper's ``accept="always"`` the whitened LM once diverged on one dataset: seed 0,
100 poses, 0.02 mm / 0.002 rad, 107 mm RMS; since the estimator holds the frame-coupled robot parameters at
nominal it converges there too, but a rule that takes every step can still run away).
The fit time is the whole ``calibrate`` call."""

from __future__ import annotations

import numpy as np

from twin.kinematics import tool2meas

from .common import PeerResult, timed
from .harness import OURS_DEFAULT, Method
from .synthetic import Problem, Split, to_dataset

__all__ = ["OURS", "ours_methods", "ours_missing"]

# (row name, estimator method, options)
OURS = (
    (OURS_DEFAULT, "best", {}),
    ("ours: LM (TM-MDH paper)", "lm", {}),
    ("ours: C-LM (TM-MDH paper)", "clm", {}),
    ("ours: separation (separation paper)", "separation", {}),
    ("ours: LM, noise-weighted, improving steps", "lm", {"weighting": "noise", "accept": "improve"}),
)


def _runner(method: str, options: dict):
    def run(problem: Problem, split: Split) -> PeerResult:
        from twin.estimator import calibrate

        ds = to_dataset(problem, split)
        settings = {"call": f"twin.estimator.calibrate(dataset, method={method!r}, **{options!r})"}
        try:
            seconds, cal = timed(lambda: calibrate(ds, method=method, **options))
        except Exception as e:  # a failure is a result of the benchmark, not a crash
            return PeerResult("ours", method, None, None, None, settings, "poses", error=f"{type(e).__name__}: {e}")
        T = tool2meas(cal.model("0"), np.asarray(split.q_val))
        return PeerResult("ours", method, T[:, :3, 3], T[:, :3, :3], seconds, settings, "positions and orientations")

    return run


def ours_methods() -> list[Method]:
    """Our methods, when ``twin.estimator`` provides them (empty otherwise: see :func:`ours_missing`)."""
    if ours_missing():
        return []
    return [
        Method(
            name=name,
            family="ours",
            data="pose",
            run=_runner(method, options),
            settings={"call": f"twin.estimator.calibrate(dataset, method={method!r})", **options},
            data_used="positions and orientations",
        )
        for name, method, options in OURS
    ]


def ours_missing() -> str | None:
    """What of ours could not be measured, or ``None``."""
    try:
        from twin.estimator import METHODS
    except ImportError:
        return "twin.estimator does not exist on this branch: our columns are missing"
    missing = [m for _, m, _ in OURS if m not in METHODS]
    return f"twin.estimator lacks methods {missing}" if missing else None

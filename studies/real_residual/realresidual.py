"""What the real robot's residual is made of: the separation paper's real-robot protocol on a
twin with non-geometric effects, repeatability, instrument noise and extra geometric error, scored against the
paper's Figures 13 and 15 read as measured data.

Evaluation code (it builds worlds and reads their truth through the campaign). The protocol is a campaign
config (``studies/real_residual/separation_real.toml``: Table 6 errors, 25 attitude + 40 position poses, checks at
500-1000 mm) measured in the cheap ``truth_noise`` mode (the world's true sphere centres + N(0, s^2) per
coordinate, no rendering). :class:`EffectMagnitudes` names what is added to that world:

* ``noise_mm``: the instrument's noise per coordinate [mm] (the paper's real binocular system; ``truth_noise``);
* ``repeatability_mm``: the robot's ISO 9283 pose repeatability RP [mm] (the world's ``repeatability`` effect:
  per-arrival joint offsets, sized by :func:`twin.world.effects_shapes.repeatability_sigma`);
* ``backlash_deg``: half clearance of every joint [deg] (``backlash``);
* ``compliance_softness``: gravity compliance with the catalogue's default stiffness divided by this factor
  (0: none; ``compliance``, 0.5 kg payload 60 mm out on the plate axis);
* ``thermal_rise_k``: warm-up of the arm over the campaign [K] (``thermal``, alpha 2.3e-5/K, tau 1800 s);
* ``extra_length_mm`` / ``extra_angle_deg``: seeded random geometric errors on every chain parameter on top of
  Table 6 (``[world] random_errors``: the paper's Table 6 may miss part of the real geometric error).

:func:`run_real_protocol` runs one world and seed and returns the before/after statistics per method;
:func:`aggregate_seeds` averages them over seeds; :func:`judge` marks a combination consistent only when the
before and after means of both figures lie within ``tol`` of the paper's. Pure: no printing, no files kept.
"""

from __future__ import annotations

import copy
import math
import tempfile
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from twin.units import M_PER_MM, rad_to_deg

__all__ = ["EffectMagnitudes", "STATISTICS", "UNITS", "campaign_raw", "run_real_protocol", "aggregate_seeds",
           "paper_real_targets", "judge", "scan_point"]

UNITS = ("angle_deg", "position_mm")
STATISTICS = ("mean", "max", "std")
_PHASES = ("before", "after")


@dataclass(frozen=True)
class EffectMagnitudes:
    """What the twin's world holds beside the Table 6 errors (mm, deg, K at this edge; see the module doc)."""

    noise_mm: float = 0.01
    repeatability_mm: float = 0.0
    backlash_deg: float = 0.0
    compliance_softness: float = 0.0
    thermal_rise_k: float = 0.0
    extra_length_mm: float = 0.0
    extra_angle_deg: float = 0.0

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"EffectMagnitudes.{k} must be a finite non-negative number, got {v!r}")

    def label(self) -> str:
        """A short label naming the nonzero magnitudes (noise always)."""
        parts = [f"noise {self.noise_mm:g} mm"]
        if self.repeatability_mm:
            parts.append(f"RP {self.repeatability_mm:g} mm")
        if self.backlash_deg:
            parts.append(f"backlash {self.backlash_deg:g} deg")
        if self.compliance_softness:
            parts.append(f"compliance x{self.compliance_softness:g}")
        if self.thermal_rise_k:
            parts.append(f"thermal +{self.thermal_rise_k:g} K")
        if self.extra_length_mm or self.extra_angle_deg:
            parts.append(f"extra geometry {self.extra_length_mm:g} mm / {self.extra_angle_deg:g} deg")
        return ", ".join(parts)


def _repeatability_sigma_deg(rp_mm: float) -> float:
    from twin.robots import irb1200
    from twin.world.effects_shapes import repeatability_sigma

    q = np.random.default_rng(0).uniform(-1.0, 1.0, size=(16, 6))  # a fixed spread of configurations
    return float(rad_to_deg(repeatability_sigma(irb1200(), q, rp_mm * M_PER_MM)))


def campaign_raw(base: Mapping[str, Any], magnitudes: EffectMagnitudes, seed: int,
                 methods: Sequence[str]) -> dict[str, Any]:
    """The campaign dict of ``base`` (the real protocol as read from TOML) with ``magnitudes`` in its world, the
    ``truth_noise`` measurement at ``noise_mm``, ``methods``, ``seed``, one in-process worker, no outputs."""
    if not methods:
        raise ValueError("methods must name at least one method")
    raw = copy.deepcopy(dict(base))
    raw.pop("quick", None)
    raw["seed"] = int(seed)
    raw["methods"] = list(methods)
    meas = dict(raw.get("measurement", {}))
    meas.update(mode="truth_noise", noise_mm=float(magnitudes.noise_mm))
    raw["measurement"] = meas
    raw["outputs"] = {**raw.get("outputs", {}), "recording": False, "figures": False}
    raw["execution"] = {"workers": 1}
    world = dict(raw.get("world", {}))
    effects = list(world.get("effects", []))
    m = magnitudes
    if m.repeatability_mm:
        effects.append({"name": "repeatability", "sigma_deg": _repeatability_sigma_deg(m.repeatability_mm),
                        "seed": int(seed)})
    if m.backlash_deg:
        effects.append({"name": "backlash", "half_clearance_deg": [float(m.backlash_deg)] * 6})
    if m.thermal_rise_k:
        effects.append({"name": "thermal", "alpha_per_k": 2.3e-5, "temp_start_c": 20.0,
                        "temp_rise_k": float(m.thermal_rise_k), "tau_s": 1800.0})
    if m.compliance_softness:
        from twin.world.effects_catalogue import DEFAULT_STIFFNESS_NM_PER_RAD

        effects.append({"name": "compliance",
                        "stiffness_nm_per_rad": [k / m.compliance_softness for k in DEFAULT_STIFFNESS_NM_PER_RAD],
                        "payload_kg": 0.5, "payload_com_mm": [0.0, 0.0, 60.0]})
    if effects:
        world["effects"] = effects
    if m.extra_length_mm or m.extra_angle_deg:
        world["random_errors"] = {"length_sigma_mm": float(m.extra_length_mm),
                                  "angle_sigma_deg": float(m.extra_angle_deg)}
    raw["world"] = world
    return raw


def _stats(block: Mapping[str, Any] | None) -> dict[str, float]:
    block = block or {}
    return {s: float(block[s]) if block.get(s) is not None else float("nan") for s in STATISTICS}


def run_real_protocol(base: Mapping[str, Any], magnitudes: EffectMagnitudes, seed: int,
                      methods: Sequence[str] = ("separation_paper",)) -> dict[str, dict[str, dict[str, dict[str, float]]]]:
    """One campaign of the protocol ``base`` with ``magnitudes`` at ``seed``: ``{method: {unit: {phase: {stat:
    value}}}}`` (units ``angle_deg`` / ``position_mm``, phases ``before`` / ``after``, statistics mean / max /
    std of the measured check errors, deg and mm). A method the estimator lacks raises ``ValueError``."""
    from twin.runner.campaign import run_campaign
    from twin.runner.config import parse_campaign_config
    from twin.runner.executor import SerialExecutor

    cfg = parse_campaign_config(campaign_raw(base, magnitudes, seed, methods))
    with tempfile.TemporaryDirectory(prefix="real_residual_") as d:
        run = run_campaign(cfg, d, executor=SerialExecutor(), recording=False, figures=False)
    missing = sorted(set(methods) - set(run.results["methods"]))
    if missing:
        raise ValueError(f"methods {missing} gave no result: {run.results.get('methods_unavailable')}")
    out: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
    for m in methods:
        meas = run.results["methods"][m]["measured"]
        out[m] = {u: {ph: _stats((meas.get(u) or {}).get(ph)) for ph in _PHASES} for u in UNITS}
    return out


def aggregate_seeds(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean and sample std over seeds of every statistic of :func:`run_real_protocol` results (one per seed):
    ``{method: {unit: {phase: {stat: {"mean", "std", "n"}}}}}``."""
    if not per_seed:
        raise ValueError("per_seed must hold at least one seed's result")
    out: dict[str, Any] = {}
    for m in per_seed[0]:
        out[m] = {}
        for u in UNITS:
            out[m][u] = {}
            for ph in _PHASES:
                out[m][u][ph] = {}
                for s in STATISTICS:
                    v = np.array([r[m][u][ph][s] for r in per_seed], dtype=float)
                    v = v[np.isfinite(v)]
                    out[m][u][ph][s] = {"mean": float(v.mean()) if v.size else float("nan"),
                                        "std": float(v.std(ddof=1)) if v.size > 1 else float("nan"),
                                        "n": int(v.size)}
    return out


def paper_real_targets(targets: Mapping[str, Any]) -> dict[str, dict[str, dict[str, float]]]:
    """The paper's real-experiment statistics ``{unit: {phase: {stat: value}}}`` from a targets dict
    (:func:`twin.evaluation.targets.read_targets`: ``real.figure13.angle_deg``, ``real.figure15.position_mm``)."""
    try:
        real = targets["real"]
        blocks = {"angle_deg": real["figure13"]["angle_deg"], "position_mm": real["figure15"]["position_mm"]}
    except (KeyError, TypeError):
        raise ValueError("targets must hold real.figure13.angle_deg and real.figure15.position_mm") from None
    return {u: {ph: {s: float(b[ph][s]) for s in STATISTICS if s in b[ph]} for ph in _PHASES} for u, b in blocks.items()}


def judge(twin: Mapping[str, Any], paper: Mapping[str, Any], *, tol: float = 0.2,
          statistic: str = "mean") -> dict[str, Any]:
    """Whether the twin reproduces the paper's real figures: each of the four ``statistic`` values (angle and
    position, before and after) within ``tol`` (relative) of the paper's. ``twin`` is ``{unit: {phase: {stat:
    value}}}`` (one method; a value may be an :func:`aggregate_seeds` entry, whose ``mean`` is used); ``paper``
    the same from :func:`paper_real_targets`. Returns the checks, ``consistent`` and the reasons it is not."""
    if not (math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive fraction, got {tol!r}")
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {STATISTICS}, got {statistic!r}")
    checks, reasons = [], []
    for u in UNITS:
        for ph in _PHASES:
            v = twin[u][ph][statistic]
            v = float(v["mean"] if isinstance(v, Mapping) else v)
            p = float(paper[u][ph][statistic])
            ratio = v / p if p else float("nan")
            ok = bool(math.isfinite(ratio) and abs(ratio - 1.0) <= tol)
            checks.append({"unit": u, "phase": ph, "statistic": statistic, "twin": v, "paper": p, "ratio": ratio,
                           "within": ok})
            if not ok:
                side = "above" if ratio > 1 else "below"
                reasons.append(f"{u.split('_')[0]} {ph} {statistic} {v:.4g} is {abs(ratio - 1) * 100:.0f} % {side} "
                               f"the paper's {p:.4g}")
    return {"consistent": not reasons, "checks": checks, "reasons": reasons, "tol": tol}


def scan_point(base: Mapping[str, Any], magnitudes: EffectMagnitudes, seeds: Sequence[int], paper: Mapping[str, Any],
               *, methods: Sequence[str] = ("separation_paper",), judged: str | None = None, tol: float = 0.2,
               run: Callable[..., Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """One combination over ``seeds``: per-seed results, their aggregate, :func:`judge` of the ``judged`` method
    (default: the first) as ``verdict`` and of every method as ``verdicts``. ``run`` replaces
    :func:`run_real_protocol` (tests)."""
    if not seeds:
        raise ValueError("seeds must hold at least one seed")
    judged = judged or methods[0]
    if judged not in methods:
        raise ValueError(f"judged must be one of methods {list(methods)}, got {judged!r}")
    fn = run or run_real_protocol
    per_seed = [fn(base, magnitudes, int(s), methods) for s in seeds]
    agg = aggregate_seeds(per_seed)
    return {"magnitudes": asdict(magnitudes), "label": magnitudes.label(), "seeds": [int(s) for s in seeds],
            "per_seed": per_seed, "aggregate": agg, "judged_method": judged,
            "verdict": judge(agg[judged], paper, tol=tol),
            "verdicts": {m: judge(agg[m], paper, tol=tol) for m in methods}}

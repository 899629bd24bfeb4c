"""A given extended model fitted without selection (:func:`fit_with_effects`): the terms a user names, fitted on the
calibration rows :func:`twin.diagnosis.diagnose.diagnose` would use and reported on its report rows; no term is chosen,
confirmed or dropped."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..estimator.calibration import Calibration
from .atoms import Atom
from .candidates import EFFECT_VOCABULARY
from .describe import describe_terms
from .diagnose import link_lengths, prepare_diagnosis
from .extend import error_stats, reduced_basis
from .features import LastMove, LoadSign
from .floor import DiagnosisError, NoiseFloor
from .pools import catalogue_atoms
from .scoring import raw_columns
from .structure import StructureTest

__all__ = ["EffectFit", "fit_with_effects"]


@dataclass(frozen=True)
class EffectFit:
    """A given extended model fitted without selection: report-row errors of the geometric-only and of the
    extended model (``{n_rows, position_mm: {...}, orientation_deg: {...}}``), the structure test of each,
    and the atom parameters."""

    before: dict[str, Any]
    after: dict[str, Any]
    test_before: StructureTest
    test_after: StructureTest
    effect_parameters: dict[str, Any]
    noise: NoiseFloor
    calibration_geometric: Calibration | None = None
    calibration: Calibration | None = None


def fit_with_effects(dataset: Dataset, atoms: list, *, holdout: float | None = None, seed: int = 0,
                     q_start: np.ndarray | None = None, geometry: dict | None = None) -> EffectFit:
    """Fit the geometric model extended by exactly ``atoms`` (no selection; every direction the data separate
    from the geometry kept) on the calibration rows, and report on the report rows :func:`diagnose` would use
    (:func:`split_held_out`; the confirmation rows when there is no report block). An entry may also be a
    catalogue family's name: every atom of that family (per joint, per link; a backlash signed by the last move).
    Returns also the geometric and the extended calibrations (``twin predict`` applies them to any rows). ``geometry``: as in :func:`diagnose`."""
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if dataset.set is None and holdout is None:
        raise DiagnosisError("fit_with_effects needs held-out rows: a 'set' column or holdout=FRACTION")
    bad = [a for a in atoms if not isinstance(a, (Atom, str))]
    if bad:
        raise ValueError(f"atoms must be twin.diagnosis.atoms.Atom or catalogue family names, got {bad[0]!r}")
    setup = prepare_diagnosis(dataset, holdout=holdout, seed=seed, q_start=q_start, geometry=geometry)
    prep, ctx, prob = setup.prep, setup.ctx, setup.problem
    # a catalogue family given by name stands for all its atoms
    fams = {a for a in atoms if isinstance(a, str)}
    if fams:
        unknown = fams - set(EFFECT_VOCABULARY)
        if unknown:
            raise ValueError(f"atoms: unknown effect families {sorted(unknown)}; known: {list(EFFECT_VOCABULARY)}")
        # a backlash by name is the sign of the last move (the load-signed one is searched over directions, the one
        # growing with the last move over laws and widths: an Atom)
        cat = [a for a in catalogue_atoms(prep.nominal, ctx, link_lengths(prep.nominal), n_points=dataset.spheres.shape[1])
               if a.family in fams and a.target != "all_lengths" and a.pool == "catalogue"
               and not any(isinstance(f, (LoadSign, LastMove)) for f in a.features)]
        atoms = [a for a in atoms if isinstance(a, Atom)] + cat
    base = prob.fit(setup.x0, [])
    rc = base.model_cal.residuals(base.z)
    Q, _ = np.linalg.qr(rc.J[:, base.free])
    chosen = []
    for a in atoms:
        E = raw_columns(base.model_cal, a, prob.features(a)[prob.rows_cal], base.z, rc)
        chosen.append((a, reduced_basis(E, Q=Q, rel_tol=1e-6, max_rank=40)))
    fit = prob.fit(setup.x0, chosen)
    atoms_json, params = describe_terms(prob, fit)
    P = prep.space.size
    geo = replace(setup.geometric, x=base.z[:P])
    ext = replace(setup.geometric, method="best+effects", x=fit.z[:P], effects=tuple(atoms_json))
    block = "rep" if prob.obs_rep is not None else "val"
    mb, mf = prob.model([], block), prob.model(chosen, block)
    keep = np.ones(mb.obs.n, bool)
    return EffectFit(
        before=error_stats(mb, base.z),
        after=error_stats(mf, fit.z),
        test_before=prob.test(base, mb, keep),
        test_after=prob.test(fit, mf, keep),
        effect_parameters=params,
        noise=setup.floor,
        calibration_geometric=geo,
        calibration=ext,
    )

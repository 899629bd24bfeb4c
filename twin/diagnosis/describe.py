"""The kept terms in words and numbers: their names and families (:func:`name_effects`), each term's size, unit
and uncertainty (:func:`describe_terms`) as ``diagnosis.json`` reports them."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..units import DEG_PER_RAD, MM_PER_M, M_PER_MM, MRAD_PER_RAD, RAD_PER_DEG
from .atoms import Atom, tilt_axis, tilt_coefficient
from .values import with_records
from .changes import is_change
from .extend import ExtendedModel
from .features import BaseMoment, Cos, Pow, Sin, feature_from_dict
from .loads import tilt_angles
from .problem import Fit, Problem, covariance

__all__ = ["name_effects", "describe_terms", "place_unit", "term_values"]



MINOR_RMS = 0.3  # an atom whose unique effect is below this RMS (in units of the floor) is reported as minor


def name_effects(atoms_json: list[dict]) -> tuple[tuple[str, ...], tuple[dict, ...], list[str]]:
    """Step 7b: the catalogue families of the non-minor named terms (``effects``), the non-minor unnamed terms, and
    notes. A named shape of one joint variable kept beside a non-minor unnamed function of the same variable at
    the same joint is one shape the catalogue does not name (a one-sided pull of a cable past some angle took a
    quadratic and a 1st harmonic of q5); measurement-side terms describe the instrument or the cell."""
    notes: list[str] = []
    merged = _merged_into_unnamed(atoms_json)
    for a, u in merged:
        notes.append(f"'{a['label']}' is reported with '{u['label']}' as one function of "
                     f"{', '.join(sorted(_joint_channels(a)))} on joint {a['target'][5:]} that the catalogue does not "
                     f"name (not as {a['family']})")
    unnamed_shape = {id(a) for a, _ in merged}
    effects = tuple(dict.fromkeys(_named_family(a) for a in atoms_json if not a["minor"] and id(a) not in unnamed_shape
                                  and _named_family(a) is not None))
    minor = [a["label"] for a in atoms_json if a["minor"]]
    if minor:
        notes.append(f"minor terms kept in the model but not named as effects (each explained less than {MINOR_RMS} "
                     f"of the floor, RMS per residual, when it entered): {'; '.join(minor)}")
    unnamed = tuple(a for a in atoms_json if a["family"] == "unnamed" and not a["minor"])
    instrument = [a["label"] for a in atoms_json if a["place"] in ("scale", "field") or a["target"] == "base"]
    if instrument:
        notes.append("terms on the measurement side (scale, field or frame of the measurements) describe the instrument or "
                     f"the cell, not the robot: {'; '.join(instrument)}")
    return effects, unnamed, notes


def _named_family(a: dict) -> str | None:
    """The catalogue family a term names: its own (none for an unnamed term); a change names none (a zero, a frame
    or a tool moved is reported in ``changes``), except a change of a joint's gravity-torque shapes (a payload hung
    on or taken off), which shows the joint deflecting under load: ``compliance``."""
    if a["family"] == "unnamed":
        return None
    if not is_change(a):
        return a["family"]
    f0 = a["features"][0] if a["features"] else {}
    return "compliance" if a["place"] == "joint" and f0.get("kind") == "gated" else None


def _joint_channels(a: dict) -> set[str]:
    """Joint variables a term's features are functions of (only pow/sin/cos features of joint angles; empty
    when any feature is of another kind: gravity, approach, time)."""
    chans = set()
    for f in map(feature_from_dict, a["features"]):
        ch = getattr(f, "ch", None)
        if not isinstance(f, (Pow, Sin, Cos)) or not (isinstance(ch, str) and ch.startswith("q")):
            return set()
        chans.add(ch)
    return chans


def _merged_into_unnamed(atoms_json: list[dict]) -> list[tuple[dict, dict]]:
    """``(named, unnamed)`` pairs of non-minor joint terms at the same joint whose named term is a function of
    joint variables all of which the unnamed one also uses."""
    out = []
    for a in atoms_json:
        if a["family"] == "unnamed" or a["minor"] or a["place"] != "joint":
            continue
        ca = _joint_channels(a)
        if not ca:
            continue
        for u in atoms_json:
            if u["family"] == "unnamed" and not u["minor"] and u["place"] == "joint" and u["target"] == a["target"] \
                    and ca <= _joint_channels(u):
                out.append((a, u))
                break
    return out


def place_unit(a: Atom) -> tuple[str, float]:
    """The display unit of an atom's effect on its place (``"deg"``, ``"ppm"``, ``"mm"``, ``"mm|deg"``) and the factor
    from SI to it."""
    if a.place == "joint":
        return "deg", DEG_PER_RAD
    if a.place in ("length", "scale"):
        return "ppm", 1e6
    if a.place in ("plate", "field") or a.target == "base_along":
        return "mm", MM_PER_M
    t = a.target
    if t in ("tool", "base"):
        return "mm|deg", 1.0
    if t.rstrip("0123456789") in ("d", "a"):
        return "mm", MM_PER_M
    return "deg", DEG_PER_RAD


def describe_terms(prob: Problem, fit: Fit, chi2_base: float | None = None,
                 entry_chi2: dict[str, float] | None = None) -> tuple[list[dict], dict[str, Any]]:
    """Every chosen atom: full parameters ``phi = B psi`` with standard deviations, its effect on its place
    over the calibration rows, words, its unique share of the explained calibration chi2 (Wald
    ``psi^T C_psi^-1 psi`` over ``chi2_base - chi2``), and whether it is minor: its ``Delta chi2`` when it
    entered the forward selection (what it explained beyond the atoms before it) is below ``MINOR_RMS^2``
    per residual (parts shared by two atoms belong to the one that entered first, the stronger)."""
    rc = fit.model_cal.residuals(fit.z)
    sw = np.sqrt(prob.w_cal[rc.row])
    J = rc.J[:, fit.free] * sw[:, None]
    C = covariance(J)
    pos = {int(f): k for k, f in enumerate(fit.free)}
    _, phis = fit.model_cal.split(fit.z)
    out: list[dict] = []
    params: dict[str, Any] = {}
    for k, (t, phi) in enumerate(zip(fit.model_cal.terms, phis)):
        a = t.atom
        idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
        Cpsi = C[np.ix_(idx, idx)]
        Cphi = t.basis @ Cpsi @ t.basis.T
        psi = fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
        wald = float(psi @ np.linalg.lstsq(Cpsi, psi, rcond=None)[0])
        explained = (chi2_base - fit.chi2) if chi2_base is not None else float("nan")
        share = float(wald / explained) if explained > 0 else float("nan")
        sd = np.sqrt(np.clip(np.diag(Cphi), 0, None))
        unit, fac = place_unit(a)
        F = prob.features(a)
        if a.place == "param" and a.target == "base_along":
            size = {"rms": float(abs(phi[0])) / M_PER_MM, "sd": float(sd[0]) / M_PER_MM, "unit": "mm"}
            words = f"{phi[0] / M_PER_MM:+.5f} +- {sd[0] / M_PER_MM:.5f} mm along the direction of its last move"
        elif a.place == "param" and a.target.startswith("tilt"):
            tilt = tilt_angles(a.features, F, phi)  # (n, 2) [rad] about the pivot frame's x and y
            rms = float(np.sqrt(np.mean(np.sum(tilt**2, axis=1))))
            # each coefficient by the axes it couples: "x" (the moment about x turning the pivot about x), "xy" (the
            # cross term of a compliance whose principal axes are turned)
            axes_of: dict[int, str] = {}
            for k, f in enumerate(a.features):
                ax, about = "xyz"[f.axis], "xyz"[tilt_axis(f, k)]
                axes_of.setdefault(tilt_coefficient(f, k), ax if ax == about else "".join(sorted(ax + about)))
            axes = [axes_of[c] for c in sorted(axes_of)]
            size = {"rms": rms * fac, "sd": None, "unit": unit,
                    "compliance_mrad_per_nm": (phi * MRAD_PER_RAD).tolist(),
                    "compliance_sd_mrad_per_nm": (sd * MRAD_PER_RAD).tolist()}
            if any(isinstance(f, BaseMoment) for f in a.features):
                # shapes of a moment whose masses are unknown: their coefficients have no unit of their own
                words = f"{rms * fac:.5f} {unit} RMS tilt over the rows ({len(phi)} shapes of the moment)"
            else:
                words = (", ".join(f"{ax}: {v * MRAD_PER_RAD:+.4g} +- {e * MRAD_PER_RAD:.2g} mrad/Nm" for ax, v, e in zip(axes, phi, sd))
                         + f" ({rms * fac:.5f} {unit} RMS tilt over the rows)")
        elif a.place == "param" and a.target in ("tool", "base"):
            eff = F @ phi.reshape(len(a.features), 6)  # (n, 6)
            size = {"rms_mm": (np.sqrt(np.mean(eff[:, :3] ** 2)) / M_PER_MM).item(),
                    "rms_deg": (np.sqrt(np.mean(eff[:, 3:] ** 2)) / RAD_PER_DEG).item()}
            words = f"{size['rms_mm']:.4f} mm / {size['rms_deg']:.5f} deg RMS over the rows"
        elif a.place == "field":
            obs = prob.obs_cal
            G = (fit.model_cal.field_grid(a) * F[prob.rows_cal][:, None, :, None])[obs.seen]  # (m, K, 3) at the points
            disp = np.einsum("mkc,k->mc", G, phi)  # (m, 3)
            rms = float(np.sqrt(np.mean(np.sum(disp**2, axis=1))))
            grad = np.einsum("mkc,mc->k", G, disp) / (len(disp) * max(rms, 1e-300))
            sd_rms = float(np.sqrt(max(grad @ Cphi @ grad, 0.0)))
            size = {"rms": rms / M_PER_MM, "sd": sd_rms / M_PER_MM, "unit": "mm"}
            words = f"{rms / M_PER_MM:.5f} +- {sd_rms / M_PER_MM:.5f} mm RMS displacement over the measured points"
        elif a.varying_plate:
            eff = F @ phi.reshape(len(a.features), 3)  # (n, 3) offset per row in the plate frame
            rms = float(np.sqrt(np.mean(np.sum(eff**2, axis=1))))
            size = {"rms": rms / M_PER_MM, "sd": float(np.sqrt(np.sum(sd**2))) / M_PER_MM, "unit": "mm"}
            words = f"{rms / M_PER_MM:.5f} mm RMS over the rows (offset in the plate frame)"
        elif a.place == "plate":
            size = {"offset_mm": (phi / M_PER_MM).tolist(), "sd_mm": (sd / M_PER_MM).tolist()}
            words = "offset (" + ", ".join(f"{v / M_PER_MM:+.4f} +- {e / M_PER_MM:.4f}" for v, e in zip(phi, sd)) + ") mm"
        else:
            eff = F @ phi
            g = F.T / max(len(F), 1)
            # sd of the RMS effect (delta method on the mean square): d rms / d phi = F^T eff / (n rms)
            rms = float(np.sqrt(np.mean(eff**2)))
            grad = (g @ eff) / max(rms, 1e-300)
            sd_rms = float(np.sqrt(max(grad @ Cphi @ grad, 0.0)))
            size = {"rms": rms * fac, "sd": sd_rms * fac, "unit": unit}
            if a.family == "cyclic" and len(phi) == 2:
                amp = float(np.hypot(*phi))
                gamp = phi / max(amp, 1e-300)
                sda = float(np.sqrt(max(gamp @ Cphi @ gamp, 0.0)))
                size.update({"amplitude": amp * fac, "amplitude_sd": sda * fac})
                words = f"amplitude {amp * fac:.5f} +- {sda * fac:.5f} {unit}"
            elif len(phi) == 1:
                words = (f"{phi[0] * fac:.5g} +- {sd[0] * fac:.2g} {unit} per unit of {a.channel} "
                         f"({rms * fac:.5f} {unit} RMS over the rows)")
            else:
                words = f"{rms * fac:.5f} +- {sd_rms * fac:.5f} {unit} RMS over the rows"
        # one number in words' units for a table: amplitude (cyclic), the single coefficient, or the RMS effect
        if "amplitude" in size:
            value, value_sd, vunit = size["amplitude"], size["amplitude_sd"], unit
        elif len(phi) == 1 and a.place not in ("plate", "field"):
            value, value_sd, vunit = float(phi[0] * fac), float(sd[0] * fac), f"{unit} per unit of {a.channel}"
        elif "compliance_mrad_per_nm" in size:
            value, value_sd, vunit = size["rms"], None, f"{unit} RMS tilt"
        elif "rms" in size:
            value, value_sd, vunit = size["rms"], size["sd"], f"{unit} RMS"
        elif "rms_mm" in size:
            value, value_sd, vunit = size["rms_mm"], None, "mm RMS (translation)"
        else:
            value, value_sd, vunit = float(np.linalg.norm(phi) * fac), None, unit
        entry = {**a.spec(), "features": [f.to_dict() for f in with_records(a.features, prob.ctx)], "pool": a.pool, "values": phi.tolist(), "sd": sd.tolist(), "reduced_dimension": int(t.r),
                 "value": value, "value_sd": value_sd, "value_unit": vunit,
                 "unique_chi2": wald, "unique_share": share, "unique_rms_floor": float(np.sqrt(wald / max(J.shape[0], 1))),
                 "entry_chi2": (entry_chi2 or {}).get(a.key, wald),
                 "minor": bool(np.sqrt((entry_chi2 or {}).get(a.key, wald) / prob.evidence_scale / max(J.shape[0], 1))
                               < MINOR_RMS),
                 "size": size, "text": f"{a.label}: {words}",
                 "unit": "SI per unit of each feature: rad (joint), relative (length, scale), m (plate), m or rad (param)"}
        out.append(entry)
        params[a.label] = {"family": a.family, "values": phi.tolist(), "sd": sd.tolist(), "size": size}
    return out, params


def term_values(model: ExtendedModel, t, phi: np.ndarray) -> np.ndarray:
    """One term of an extended model on its rows ``(n,)``, in its place's display unit."""
    _, fac = place_unit(t.atom)
    if t.atom.place == "param" and t.atom.target in ("tool", "base"):
        return np.linalg.norm((t.F @ phi.reshape(len(t.atom.features), 6))[:, :3], axis=1) / M_PER_MM
    if t.atom.place == "plate":
        return np.linalg.norm(t.F @ phi.reshape(len(t.atom.features), 3), axis=1) / M_PER_MM
    if t.atom.target == "base_along":
        return np.linalg.norm(t.F, axis=1) * phi[0] / M_PER_MM
    if t.atom.place == "param" and t.atom.target.startswith("tilt"):
        return np.linalg.norm(tilt_angles(t.atom.features, t.F, phi), axis=1) * fac
    if t.atom.place == "field":
        obs = model.obs
        disp = np.linalg.norm(np.einsum("nskc,k->nsc", model.field_grid(t.atom) * t.F[:, None, :, None], phi), axis=2)
        return np.sqrt(np.sum(disp**2, axis=1) / np.maximum(obs.seen.sum(1), 1)) / M_PER_MM
    return (t.F @ phi) * fac

"""The two pools of atoms the selection draws from (:mod:`twin.diagnosis.atoms` describes atoms and places): the
named catalogue (:func:`catalogue_atoms`: the physical effects of :data:`~twin.diagnosis.candidates.EFFECT_VOCABULARY`,
split per joint, harmonic order, link and sphere, with the arm's own load terms of :mod:`twin.diagnosis.loads`) and
the unnamed dictionary (:func:`generic_atoms`: every place against every smooth basis of every channel). Features'
constants are fixed on the rows the pools are built on. Nothing here reads truth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..kinematics import RobotModel
from ..units import M_PER_MM, RAD_PER_DEG
from .atoms import (BACKLASH_MOVE_LAWS, BACKLASH_MOVE_WIDTHS_DEG, HINGE_POINTS, Atom, hinge_atom, joint_words,
                    sign_backlash)
from .candidates import RowContext, carried_moments, gravity_torque_regressor, gravity_torques, has_masses
from .features import (CartDir, Const, Cos, Exp, Feature, Gated, GravityDir, Heat, Lag, LastMove, Moment, Pow,
                       Prod, Settle, Sign, Sin, Station, Step, StepIn, Torque)
from .field import field_applicable, field_atom_specs, field_constants
from .loads import load_atoms, torque_shapes
from .values import channel, motion_heat

__all__ = ["catalogue_atoms", "generic_atoms", "heat_alternatives", "heat_variants", "recorded_lag_atoms",
           "wrist_couplings"]


SCAN_ORDERS = (1.5, 150.0, 0.5)  # cyclic-error orders scanned (beyond the integers 1-3): first, last, step
MOVE_WIDTHS_DEG = (2.0, 6.0, 20.0)  # widths of the move-size hysteresis shapes in the dictionary (then refined)
TAU_FRACTIONS = (0.125, 0.5, 2.0)  # time constants of transients and lags, as fractions of the campaign's span (then refined)
ONSET_QUANTILES = (0.2, 0.4, 0.6)  # onsets of the air's change without a temperature record, on the rows' times (refined)
MIN_THERMAL_LENGTH = 0.01  # [m] links shorter than this get no thermal atom of their own
TIME_CYCLES = tuple(np.arange(1.5, 20.01, 0.5))  # cycles over the campaign of the periodic time terms (then refined)
WRIST_COUPLINGS = ((5, 4), (6, 4), (6, 5))  # (driven joint, driving joint) of a 6R arm: wrist drive shafts pass through joints 4, 5
HINGE_POWERS = (1, 2)  # the pull grows linearly (a spring) or with the square of the overtravel
COMPLIANCE_RANK = 3  # principal gravity-torque shapes kept per joint
_ORD = {1: "1st", 2: "2nd", 3: "3rd"}


def _norm(x: np.ndarray) -> tuple[float, float]:
    c = float(np.mean(x))
    h = float(max(0.5 * np.ptp(x), 1e-9))
    return c, h


def _nominal_length(model: RobotModel, name: str) -> float:
    """The nominal value [m] of length parameter ``name`` of ``model`` (``"a3"``, ``"d4"``; a ``"urdf"`` chain's
    ``"<joint>.xyz"``: the length of the joint's origin translation)."""
    if name.endswith(".xyz"):
        j = name[: -len(".xyz")]
        return float(np.linalg.norm([model.params[model.layout.index(f"{j}.{c}")] for c in "xyz"]))
    return float(model.params[model.layout.index(name)])


def wrist_couplings(model: RobotModel) -> tuple[tuple[int, int], ...]:
    """``(driven, driving)`` 1-based joint pairs whose drives may be coupled: the last three joints of the chain
    when they are revolute (a wrist whose drive shafts pass through the joints before; a 6R arm's 5-4, 6-4, 6-5)."""
    N = model.n_joints
    if N < 3 or any(model.joint_kinds[j] != "revolute" for j in range(N - 3, N)):
        return ()
    a, b, c = N - 2, N - 1, N
    return ((b, a), (c, a), (c, b))


def _session_starts(ctx: RowContext) -> list[tuple[str, float]]:
    """``(time channel, value)`` at the first row of every session after the first (a gap in ``t_s`` or a
    recorded restart: ``ctx.session_start``)."""
    if ctx.session_start is None:
        return []
    tch = _time_channel(ctx) or "row"
    tv = channel(ctx, tch)
    rows = np.flatnonzero(np.asarray(ctx.session_start, bool))
    return [(tch, float(tv[r])) for r in rows if r > 0]


def _time_channel(ctx: RowContext) -> str | None:
    if ctx.t_s is not None and np.ptp(ctx.t_s) > 0:
        return "t_s"
    return None


def _time_features(ctx: RowContext, ch: str) -> list[Feature]:
    c, h = _norm(channel(ctx, ch))
    return [Pow(ch=ch, p=1, c=c, h=h)]


def catalogue_atoms(model: RobotModel, ctx: RowContext, length_names: list[str], *,
                    harmonic_orders: tuple[int, ...] = (1, 2, 3), n_points: int = 3,
                    whole_orders: bool = True, values: dict | None = None) -> list[Atom]:
    """The named pool (see the module docstring), built on the nominal ``model`` and the rows of ``ctx``
    (``n_points``: the points of the marker set, one ``plate_geometry`` atom each). Any serial chain: its joints
    by index (``theta<j>``, ``q<j>``, 1-based) and in words by name (:func:`joint_words`); harmonics, cyclic
    scans and the wrist couplings for revolute joints only; with the chain's mass properties (a URDF's
    inertials), compliance under the gravity load they give and the tilt of each joint's support (and of the
    base) under the gravity moment it carries. ``whole_orders``: the cyclic scan takes whole cycles per joint turn
    only (a physical period); half orders only where terms are confirmed on another session. ``values``: as
    :func:`twin.diagnosis.loads.load_atoms`'."""
    atoms: list[Atom] = []
    N = model.n_joints
    jw = lambda j: joint_words(model, j)  # noqa: E731
    revolute = [k == "revolute" for k in model.joint_kinds]
    # compliance: dtheta_i = c_i tau_i(q), tau_i linear in the mass moments (m_k, h_k = m_k c_k) of links
    # k >= i. The linear relaxation has up to 24 columns per joint; with a generic prior on the moments
    # (masses of one order, centres of mass ~0.1 m off the link frames) the torques a real arm can have
    # lie close to the leading COMPLIANCE_RANK principal shapes of the prior-weighted columns on these rows:
    # the atom keeps those (a broad atom would collect a little of every other effect).
    Y = gravity_torque_regressor(model, ctx.q)
    for i in range(1, N + 1):
        shapes = torque_shapes(model, ctx.q, i, Y=Y)
        if not shapes:
            continue
        atoms.append(Atom("compliance", "joint", f"theta{i}", shapes[:COMPLIANCE_RANK], f"gravity torque of joint {i}",
                          f"joint {jw(i)} compliance under gravity", "catalogue", (i,)))
        for tch, at in _session_starts(ctx):
            # a payload added (or a brake set) at a restart changes the torque from then on
            atoms.append(Atom("compliance", "joint", f"theta{i}",
                              tuple(Gated(f=f, ch=tch, at=at) for f in shapes[:COMPLIANCE_RANK]),
                              f"gravity torque of joint {i} from {tch} >= {at:.6g}",
                              f"joint {jw(i)} compliance under gravity, changed at the restart ({tch} >= {at:.6g})",
                              "catalogue", (i,)))
        if len(shapes) > COMPLIANCE_RANK:
            # the further shapes (a payload, wrist masses): a broad atom, tried after the small ones
            atoms.append(Atom("compliance", "joint", f"theta{i}", shapes[COMPLIANCE_RANK:3 * COMPLIANCE_RANK],
                              f"gravity torque of joint {i} (further shapes)",
                              f"joint {jw(i)} compliance under gravity, further torque shapes", "catalogue", (i,)))
    if has_masses(model):
        # with the chain's mass properties the load is known: one stiffness per joint, dq_i = c_i tau_i(q)
        tau = gravity_torques(model, ctx.q)
        for i in range(1, N + 1):
            t = tau[:, i - 1]
            if np.ptp(t) <= 1e-9 * max(1.0, float(np.max(np.abs(t)))):
                continue  # a constant load (a vertical lift carries the same weight everywhere): the offset holds it
            what = "force along it" if model.joint_kinds[i - 1] == "prismatic" else "torque about it"
            atoms.append(Atom("compliance", "joint", f"theta{i}", (Torque(j=i, h=1.0),),
                              f"gravity load of joint {i} (URDF masses)",
                              f"joint {jw(i)} compliance under gravity (the {what} from the URDF masses)",
                              "catalogue", (i,)))
        # the support of a joint (a column, a bearing, the base on its wheels or a pedestal) tilting about two
        # axes of its frame under the gravity moment of everything it carries, one compliance per axis
        for i in range(0, N + 1):
            M = carried_moments(model, ctx.q, i)
            feats = tuple(Moment(j=i, axis=a, h=1.0) for a in (0, 1)
                          if np.ptp(M[:, a]) > 1e-9 * max(1.0, float(np.max(np.abs(M[:, a])))))
            if len(feats) < 2:
                continue
            where = ("the robot's base tilting about its horizontal axes" if i == 0 else
                     f"the support of joint {jw(i)} tilting about its x and y axes")
            atoms.append(Atom("tilt", "param", f"tilt{i}", feats, f"gravity moment carried by {'the base' if i == 0 else f'joint {i}'}",
                              f"{where} under the gravity moment it carries (URDF masses)", "catalogue",
                              (i,) if i else ()))
            # stiffer about one horizontal axis than the other, the principal axes turned anywhere: a symmetric
            # compliance, its cross term turning the pivot about x with the moment about y and about y with x
            cross = (Moment(j=i, axis=0, h=1.0, shape=0), Moment(j=i, axis=1, h=1.0, shape=1),
                     Moment(j=i, axis=1, h=1.0, about=0, shape=2), Moment(j=i, axis=0, h=1.0, about=1, shape=2))
            atoms.append(Atom("tilt", "param", f"tilt{i}", cross,
                              f"gravity moment carried by {'the base' if i == 0 else f'joint {i}'}, axes turned",
                              f"{where} under the gravity moment it carries, stiffer about one axis than the other "
                              "(URDF masses)", "catalogue", (i,) if i else ()))
    for j in range(1, N + 1):
        atoms.append(sign_backlash(j, jw(j)))
        for w, law in ((w, law) for law in BACKLASH_MOVE_LAWS for w in BACKLASH_MOVE_WIDTHS_DEG):
            # a backlash whose size follows the size of the last move (the gear taken up by a short move only part
            # of the way, or wound up in proportion to it): signed by the last move, saturating smoothly
            # (tanh(move / w)) or in proportion up to w (clip(move / w, -1, 1)), the width refined when kept;
            # w -> 0 is the sign backlash
            unit, scale = ("deg", RAD_PER_DEG) if revolute[j - 1] else ("mm", M_PER_MM)
            ch = f"{'tanh' if law is None else 'clip'}(last move j{j} / {w:.3g} {unit})"
            atoms.append(Atom("backlash", "joint", f"theta{j}", (LastMove(j=j, w=w * scale, law=law),), ch,
                              f"joint {jw(j)} backlash growing with the size of its last move ({ch})", "catalogue", (j,)))
        if revolute[j - 1]:
            for k in harmonic_orders:
                atoms.append(Atom("cyclic", "joint", f"theta{j}",
                                  (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)),
                                  f"sin/cos({k} q{j})", f"joint {jw(j)}, {_ORD.get(k, f'{k}th')} harmonic", "catalogue", (j,),
                                  {"order": k}))
        atoms.append(Atom("gear_ratio", "joint", f"theta{j}", (Pow(ch=f"q{j}", p=1, c=0.0, h=1.0),),
                          f"q{j}", f"joint {jw(j)} gear-ratio error (theta_{j} grows with q{j})" if revolute[j - 1] else
                          f"joint {jw(j)} travel scale error (its offset grows with q{j})", "catalogue", (j,)))
    # cyclic errors of the motor-side stages: k = N h cycles per joint turn (gear ratios of 50-150 are usual): whole
    # orders (a pool of their own: its size enters the evidence threshold). A stage with a non-integer ratio (a
    # belt, an intermediate gear) is scanned on a half-order grid and its order refined only where a term is
    # confirmed on another session: on one session's pose pattern a free period fits the pattern, not the robot
    for j in range(1, N + 1):
        if np.ptp(ctx.q[:, j - 1]) < 1e-6 or not revolute[j - 1]:
            continue
        for k in np.arange(SCAN_ORDERS[0], SCAN_ORDERS[1] + 1e-9, SCAN_ORDERS[2]):
            k = float(k)
            if whole_orders and k != round(k):
                continue
            if k in harmonic_orders or k * np.ptp(ctx.q[:, j - 1]) < 1.5 * (2 * np.pi):
                continue  # a period is evidence only where the rows see it repeat (1.5 periods over the range)
            atoms.append(Atom("cyclic", "joint", f"theta{j}",
                              (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)),
                              f"sin/cos({k:.4g} q{j})", f"joint {jw(j)}, harmonic of order {k:.4g} (cycles per joint turn)",
                              "scan", (j,), {"order": k}))
    # wrist coupling: the drives of the last two joints pass through the one before (a 6R arm's 5 and 6 through 4,
    # 6's through 5): a coupling-ratio error turns the driven joint with the driving one
    for jd, js in wrist_couplings(model):
        atoms.append(Atom("coupling", "joint", f"theta{jd}", (Pow(ch=f"q{js}", p=1, c=0.0, h=1.0),),
                          f"q{js}", f"wrist coupling (theta{jd} follows q{js})", "catalogue", (js, jd)))
    # thermal growth: each link, and all links together, against temp_c (linear) or a cubic in t_s
    if ctx.temp_c is not None and np.ptp(ctx.temp_c) > 0:
        ref = float(np.median(ctx.temp_c))
        feats = (Pow(ch="temp_c", p=1, c=ref, h=1.0),)
        ch = "temp_c"
    elif _time_channel(ctx):
        feats = tuple(_time_features(ctx, "t_s"))
        ch = "t_s"  # linear: a polynomial in time goes where the rows are not (later rows), a warm-up settles
    else:
        feats = ()
    variants = [(feats, ch)] if feats else []
    # a link's temperature lags the recorded one (the air's, a sensor elsewhere on the arm): the temperature
    # through a first-order lag; without a temperature, the warm-up as a transient 1 - exp(-t / tau) beside the
    # linear drift. And whatever the air does, the motors heat the arm with its motion: each link against the
    # joints' travel through a first-order lag (heat in per move, out with tau). Time constants on a coarse
    # grid, refined when an atom is kept.
    span = float(np.ptp(ctx.t_s)) if _time_channel(ctx) else 0.0
    if span > 0:
        for tau in (fr * span for fr in TAU_FRACTIONS):
            if ch == "temp_c":
                f = Lag(ch="temp_c", tau=float(tau), c=ref, h=1.0)
                variants.append(((f,), f"temp_c lagged {tau:.4g} s"))
            else:
                f = Exp(ch="t_s", t0=float(ctx.t_s[0]), tau=float(tau))
                variants.append(((f,), f"warm-up 1-exp(-t/{tau:.4g} s)"))
                if tau < span:
                    # the air changed later (a door opened, the heating switched): a step at an onset through the
                    # links' lag (onset, ramp and lag refined when tried: twin.diagnosis.refine.refine_onset)
                    for at in np.quantile(ctx.t_s, ONSET_QUANTILES):
                        f = Exp(ch="t_s", t0=float(at), tau=float(tau))
                        variants.append(((f,), f"the air's step at t_s {at:.6g}, lagged {tau:.4g} s"))
            # the motors' heat: each link against the joints' travel through a first-order lag
            variants += heat_variants(ctx, float(tau))
    for fs, chan in variants:
        atoms += _thermal_atoms(model, fs, chan, length_names)
    for s in range(n_points):
        atoms.append(Atom("plate_geometry", "plate", f"sphere{s}", (Const(),), "constant",
                          f"sphere {s} off its nominal plate position", "catalogue"))
    # the arm's own load without its masses: backlash signed by the load, the base tilting under the arm's moment
    return atoms + load_atoms(model, ctx, values=values)


def _thermal_atoms(model: RobotModel, fs: tuple[Feature, ...], chan: str, length_names: list[str]) -> list[Atom]:
    """Thermal growth against the features ``fs`` (channel ``chan``): of all link lengths together and of each link."""
    atoms = [Atom("thermal", "length", "all_lengths", fs, chan, f"thermal growth of all link lengths vs {chan}",
                  "catalogue")]
    for L in length_names:
        if abs(_nominal_length(model, L)) < MIN_THERMAL_LENGTH:
            continue  # a link of nominal length ~0 (a2 of the IRB 1200) has no length to grow
        atoms.append(Atom("thermal", "length", L, fs, chan, f"thermal growth of link {L} vs {chan}", "catalogue"))
    return atoms


def recorded_lag_atoms(model: RobotModel, ctx: RowContext, length_names: list[str]) -> list[Atom]:
    """The catalogue's thermal growth of all links and of each link against the recorded temperature through a lag
    (its grid's middle time constant; none without a temperature that varies or without row times): the templates
    of a change of the air the campaign's last rows record (:func:`twin.diagnosis.late.end_term`) where no selection
    ran."""
    if ctx.temp_c is None or not np.ptp(ctx.temp_c) > 0 or not _time_channel(ctx):
        return []
    tau = float(TAU_FRACTIONS[len(TAU_FRACTIONS) // 2] * np.ptp(ctx.t_s))
    f = Lag(ch="temp_c", tau=tau, c=float(np.median(ctx.temp_c)), h=1.0)
    return _thermal_atoms(model, (f,), f"temp_c lagged {tau:.4g} s", length_names)


def heat_variants(ctx: RowContext, tau: float) -> list[tuple[tuple[Feature, ...], str]]:
    """The catalogue's readings of the motors' heat at the time constant ``tau`` [s] (features and channel): the arm's
    motors (joints 1-3) and the wrist's (4-6) each heating what is near them, with the holding current's warm-up from
    servo-on beside them (the same lag applied to a constant input); one group of motors alone; one motor alone (any
    joint that moves: how far it travels beside the others says nothing of how much its motor heats, a wrist joint
    sweeping a wide range beside a shoulder joint that moves little). A warm-up is the groups' atom only: beside one
    group or one motor it would follow any smooth drift of the cell, a recorded temperature's too."""
    N = ctx.q.shape[1]
    groups = [tuple(js) for js in (range(1, N - 2), range(N - 2, N + 1)) if len(js)]
    heat = [Heat(tau=float(tau), joints=js, h=float(max(np.mean(motion_heat(ctx, float(tau), js)), 1e-9)))
            for js in groups]
    out = [((*heat, Exp(ch="t_s", t0=float(ctx.t_s[0]), tau=float(tau))), f"motion heat lagged {tau:.4g} s")]
    out += [((f,), f"joints {js[0]}-{js[-1]}'s motion heat lagged {tau:.4g} s") for js, f in zip(groups, heat)
            if len(js) > 1]
    for j in range(1, N + 1):
        h = float(np.mean(motion_heat(ctx, float(tau), (j,))))
        if h > 0:
            out.append(((Heat(tau=float(tau), joints=(j,), h=h),), f"joint {j}'s motion heat lagged {tau:.4g} s"))
    return out


def heat_alternatives(ctx: RowContext, atom: Atom) -> list[Atom]:
    """The thermal ``atom`` against the motors' heat (:class:`~twin.diagnosis.features.Heat` features) read with the
    other joint sets of :func:`heat_variants` at its time constant: the same link(s)' growth with the heat of other
    motors."""
    tau = next(f.tau for f in atom.features if isinstance(f, Heat))
    mine = tuple(f.joints if isinstance(f, Heat) else None for f in atom.features)
    what = atom.label.split(" vs ")[0]
    return [replace(atom, features=fs, channel=ch, label=f"{what} vs {ch}")
            for fs, ch in heat_variants(ctx, tau)
            if tuple(f.joints if isinstance(f, Heat) else None for f in fs) != mine]


def generic_atoms(model: RobotModel, ctx: RowContext, param_names: list[str], length_names: list[str],
                  catalogue: list[Atom], *, n_change_points: int = 9, points: np.ndarray | None = None,
                  plate_spheres: np.ndarray | None = None) -> list[Atom]:
    """The unnamed dictionary: every place against every smooth basis of every channel (module docstring).
    Atoms whose columns equal a catalogue atom's are left out (the catalogue names them). ``points``: the
    measured points ``(n, K, 3)`` [m] in the measurement frame (NaN where not seen), for the field
    atoms' constants (none without them); ``plate_spheres`` ``(K, 3)`` [m]: the nominal points in the
    plate frame (their plane's normal, for the field that follows the plate's tilt). Any serial chain: harmonics
    of revolute joints only, a prismatic joint's move widths in millimetres."""
    q = ctx.q
    N = model.n_joints
    revolute = [k == "revolute" for k in model.joint_kinds]
    jw = lambda j: joint_words(model, j)  # noqa: E731
    couplings = wrist_couplings(model)
    feats: list[tuple[str, Feature | tuple, tuple[int, ...]]] = []  # (channel label, feature(s), joints)
    for j in range(1, N + 1):
        c, h = _norm(q[:, j - 1])
        if np.ptp(q[:, j - 1]) < 1e-6:
            continue
        for p in (1, 2, 3):
            # a polynomial of degree p (all lower powers with it: a centred power alone cannot follow an
            # offset curve)
            feats.append((f"q{j}^{p}" if p > 1 else f"q{j}",
                          tuple(Pow(ch=f"q{j}", p=e, c=c, h=h) for e in range(1, p + 1)), (j,)))
        if revolute[j - 1]:
            for k in (1, 2, 3):
                feats.append((f"sin/cos({k} q{j})", (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)), (j,)))
        feats.append((f"approach_sign_j{j}", Sign(j=j), (j,)))
        for w_deg in MOVE_WIDTHS_DEG:
            # hysteresis that follows the size of the last move (friction-like), on the joint angles only
            if revolute[j - 1]:
                feats.append((f"tanh(last move j{j} / {w_deg:.3g} deg)", LastMove(j=j, w=w_deg * RAD_PER_DEG), (j,)))
            else:
                feats.append((f"tanh(last move j{j} / {w_deg:.3g} mm)", LastMove(j=j, w=w_deg * M_PER_MM), (j,)))
        # the step into this row (zero for a repeat): a joint still settling from the move it just made
        feats.append((f"step into the row j{j}", StepIn(j=j), (j,)))
    for a in range(1, N + 1):
        for b in range(a + 1, N + 1):
            if np.ptp(q[:, a - 1]) < 1e-6 or np.ptp(q[:, b - 1]) < 1e-6:
                continue
            ca, ha = _norm(q[:, a - 1])
            cb, hb = _norm(q[:, b - 1])
            # the product with both linear terms (a centred product alone leaves a linear remainder)
            feats.append((f"q{a}*q{b}", (Pow(ch=f"q{a}", p=1, c=ca, h=ha),
                                         Pow(ch=f"q{b}", p=1, c=cb, h=hb),
                                         Prod(ch=(f"q{a}", f"q{b}"), c=(ca, cb), h=(ha, hb))),
                          (a, b)))
    for ax, nm in enumerate("xyz"):
        feats.append((f"gravity_dir_flange_{nm}", GravityDir(axis=ax), ()))
    # time: only in t_s (a term in the row count says nothing of the next session); linear, change points,
    # settling transients and (on the cell) oscillations; no higher polynomial in time: it goes where the rows are
    # not (the next rows, later), and a blind campaign's re-seated plate, fitted with t^2, was predicted 13x worse
    # than its oracle on the rows after the campaign
    tch = _time_channel(ctx)
    span = 0.0
    if tch is not None:
        tv = channel(ctx, tch)
        c, h = _norm(tv)
        feats.append((tch, (Pow(ch=tch, p=1, c=c, h=h),), ()))
        for qq in np.linspace(0, 1, n_change_points + 2)[1:-1]:
            at = float(np.quantile(tv, qq))
            feats.append((f"step({tch} >= {at:.6g})", Step(ch=tch, at=at), ()))
        span = float(np.ptp(tv))
        for tau in (fr * span for fr in TAU_FRACTIONS):
            # a transient that settles (warm-up of the robot, the camera mount, the cell): extrapolates as it settles
            feats.append((f"1-exp(-{tch}/{tau:.4g})", Exp(ch=tch, t0=float(tv[0]), tau=float(tau)), ()))
    # a change at a session start (a restart, another day) is a term of the sessions, located by t_s or the row
    starts = _session_starts(ctx)
    sch = tch or "row"
    for _, at in starts:
        feats.append((f"step({sch} >= {at:.6g}) (restart)", Step(ch=sch, at=at), ()))
    if len(starts) > 1:
        # a change at every restart (a joint re-homed, a plate re-seated each time): one term, a step at each
        feats.append(("a step at every session start", tuple(Step(ch=sch, at=at) for _, at in starts), ()))
    if ctx.temp_c is not None and np.ptp(ctx.temp_c) > 0:
        c, h = _norm(ctx.temp_c)
        for p in (1, 2):
            feats.append(("temp_c" if p == 1 else "temp_c^2",
                          tuple(Pow(ch="temp_c", p=e, c=c, h=h) for e in range(1, p + 1)), ()))
        if tch == "t_s":
            for tau in (fr * span for fr in TAU_FRACTIONS):
                feats.append((f"temp_c lagged {tau:.4g} s", Lag(ch="temp_c", tau=float(tau), c=c, h=h), ()))
    if ctx.station is not None:
        names = sorted(set(np.asarray(ctx.station).astype(str).tolist()))
        if len(names) > 1:
            for s in names:
                feats.append((f"station=={s}", Station(name=s), ()))

    # an oscillation in time (the air conditioning's cycle swaying a stand, warming a mount): on the cell's
    # places only (the measurement frame and scale), the period refined when kept
    cell_feats = []
    if span > 0:
        for cyc in TIME_CYCLES:
            k = 2 * np.pi * cyc / span
            cell_feats.append((f"sin/cos(2pi {tch}/{span / cyc:.4g})", (Sin(ch=tch, k=float(k)),
                                                                        Cos(ch=tch, k=float(k))), ()))
    places: list[tuple[str, str, str, tuple[int, ...]]] = [
        ("joint", f"theta{j}", f"joint {jw(j)} " + ("angle" if revolute[j - 1] else "position"), (j,))
        for j in range(1, N + 1)]
    places += [("param", p, f"parameter {p}", ()) for p in param_names]
    places += [("param", "tool", "tool (plate) frame", ()), ("param", "base", "base (measurement) frame", ()),
               ("scale", "meas_scale", "measurement scale", ())]
    cat_keys = {(a.place, a.target, _fkey(a.features)) for a in catalogue}
    atoms = []
    for place, target, pl_words, pj in places:
        for ch, f, fj in feats:
            fs = f if isinstance(f, tuple) else (f,)
            f0 = fs[0]
            if isinstance(f0, (LastMove, StepIn)) and place != "joint":
                continue
            if isinstance(f0, Sign) and not (place == "joint" and (int(target[5:]), f0.j) in couplings):
                # a joint's motion history acts on that joint (the catalogue's backlash) or on a joint its drive
                # passes through (a wrist coupling), not on another joint's frame or the cell
                continue
            if (place, target, _fkey(fs)) in cat_keys:
                continue
            if place == "joint" and len(fs) == 1 and isinstance(f0, Pow) and f0.p == 1 and f0.ch == target.replace("theta", "q"):
                continue  # = gear_ratio up to the geometry's constant
            if place == "joint" and isinstance(f0, (Sin, Cos)) and f0.ch == target.replace("theta", "q"):
                continue  # = cyclic
            if place == "joint" and isinstance(f0, Sign) and f0.j == int(target[5:]):
                continue  # = backlash
            if place == "joint" and len(fs) == 1 and isinstance(f0, Pow) and f0.p == 1 and \
                    (int(target[5:]), int(f0.ch[1:]) if f0.ch.startswith("q") else 0) in couplings:
                continue  # = coupling
            if place == "param" and target in length_names and getattr(f0, "ch", None) in ("temp_c", "t_s") and isinstance(f0, Pow) \
                    and len(fs) <= (1 if f0.ch == "temp_c" else 3):
                continue  # = thermal (absolute instead of relative: the same column)
            if place == "param" and target in length_names and isinstance(f0, (Lag, Exp)):
                continue  # = thermal with a lag or a warm-up (absolute instead of relative)
            joints = tuple(sorted(set(pj) | set(fj)))
            if place == "scale":
                # the geometry cannot absorb a constant scale (the plate's size pins it), and the features are
                # centred: the scale atom carries its own constant (s = s0 + s1 f)
                fs = (Const(),) + fs
            atoms.append(Atom("unnamed", place, target, fs, ch, f"unnamed: {pl_words} varies with {ch}", "generic", joints))
    # a station's instrument settling after it was set up (a tripod foot sinking, a mount relaxing): a transient
    # from each station's first row, on the measurement frame
    if ctx.station is not None and tch == "t_s" and span > 0:
        st = np.asarray(ctx.station).astype(str)
        t_first = {s: float(tv[np.flatnonzero(st == s)[0]]) for s in sorted(set(st.tolist()))}
        for tau in (fr * span for fr in TAU_FRACTIONS):
            # one transient per station (each set-up settles its own way, about its own axis)
            cell_feats.append((f"settling since set-up 1-exp(-t/{tau:.4g})",
                               tuple(Settle(tau=float(tau), t0=tuple(t_first.items()), only=s) for s in t_first), ()))
    for place, target, pl_words in (("param", "base", "base (measurement) frame"), ("scale", "meas_scale", "measurement scale")):
        for ch, fs, _ in cell_feats:
            fs = ((Const(),) if place == "scale" else ()) + fs
            atoms.append(Atom("unnamed", place, target, fs, ch, f"unnamed: {pl_words} varies with {ch}", "generic"))
    # a pull that starts past an angle (a cable or dress pack going taut): zero on one side of the angle, a power of
    # the overtravel beyond it, on the joint itself; the angle on the deciles of the joint's range (then refined)
    for j in range(1, N + 1):
        x = q[:, j - 1]
        if np.ptp(x) < 1e-6:
            continue
        for at in np.quantile(x, np.linspace(0, 1, HINGE_POINTS + 2)[1:-1]):
            for side in (1, -1):
                for pw in HINGE_POWERS:
                    atoms.append(hinge_atom(j, float(at), side, pw, float(max(0.5 * np.ptp(x), 1e-9)),
                                            prismatic=not revolute[j - 1], words=jw(j)))
    # the flange stops short of (or beyond) its target along its last move (settling): a displacement in the
    # base frame along the direction of the last Cartesian move
    tcp = [0.0, 0.0, 0.0] if plate_spheres is None else np.mean(np.asarray(plate_spheres, float), axis=0).tolist()
    atoms.append(Atom("unnamed", "param", "base_along", tuple(CartDir(axis=a, tcp=tuple(tcp)) for a in range(3)),
                      "direction of the last Cartesian move", "unnamed: the flange is displaced along its last Cartesian move",
                      "generic"))
    for sph in range(0 if plate_spheres is None else len(plate_spheres)):
        # a sphere that moves on the plate with the direction of gravity (loose in its seat, a flexing holder)
        atoms.append(Atom("unnamed", "plate", f"sphere{sph}", tuple(GravityDir(axis=ax) for ax in range(3)),
                          "gravity_dir_flange", f"unnamed: sphere {sph} moves on the plate with the gravity direction",
                          "generic"))
    if points is not None:
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if field_applicable(P):
            n_tool = None
            if plate_spheres is not None and len(plate_spheres) >= 3:  # one or two points span no plate normal
                S = np.asarray(plate_spheres, dtype=float)
                n = np.cross(S[1] - S[0], S[2] - S[0])
                if np.linalg.norm(n) > 0:
                    n_tool = n / np.linalg.norm(n) * (1.0 if n[2] >= 0 else -1.0)
            stations = sorted(set(np.asarray(ctx.station).astype(str).tolist())) if ctx.station is not None else None
            specs = field_atom_specs(field_constants(P), n_tool, stations)
            for ch, fs, words in specs:
                atoms.append(Atom("unnamed", "field", "meas_field", fs, ch, f"unnamed: {words}", "generic"))
            if _time_channel(ctx):
                # the instrument warming up after switch-on: its scale and range errors settle with time (here
                # the time channel is t_s, and span its range)
                for ch, fs, words in specs:
                    if ch not in ("scale vs depth", "range error vs range", "range error vs range^2"):
                        continue
                    for tau in (fr * span for fr in TAU_FRACTIONS):
                        ft = tuple(replace(f, t0=float(ctx.t_s[0]), tau=float(tau)) for f in fs)
                        if ch == "range error vs range^2":
                            # a stereo bar bending as it warms: the convergence error was already growing when
                            # the first row was measured (switched on earlier), so the field's constant part
                            # comes with it: G (c0 + c1 (1 - exp(-(t - t0) / tau)))
                            ft = fs + ft
                        atoms.append(Atom("unnamed", "field", "meas_field", ft, f"{ch}, warm-up 1-exp(-t_s/{tau:.4g})",
                                          f"unnamed: {words}, growing as the instrument warms up (1-exp(-t_s/{tau:.4g}))",
                                          "generic"))
    return atoms


def _fkey(features) -> str:
    return repr([(f.kind, getattr(f, "ch", None), getattr(f, "k", None), getattr(f, "p", None), getattr(f, "j", None),
                  getattr(f, "axis", None), getattr(f, "tau", None)) for f in features])

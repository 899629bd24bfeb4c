"""Atoms: the smallest effect terms diagnosis selects from, each one channel acting at one place.

An *atom* is ``delta(place) = sum_k phi_k f_k(row)``: a few *features* ``f_k`` (functions of what was
recorded for the row: commanded joints, their approach directions, ``t_s``, ``temp_c``, the row order, the
station) acting at one *place* of the model:

==========  =============================================================================================
``joint``   a joint angle (``target = "theta3"``): the robot reaches ``q_j + delta`` (applied exactly)
``length``  a link length, relative (``"a2"``, or ``"all_lengths"``): ``L -> L (1 + delta)`` (first order)
``param``   any parameter of the estimator's vector (``"alpha3"``, ``"tool_rz"``, ``"d4"`` absolute [m]);
            ``"tool"`` / ``"base"`` name the whole 6-DOF frame (six columns per feature; ``base`` acts on
            the station of each row), ``"base_along"`` a displacement in the robot base frame along the
            direction its three features give, one coefficient (first order)
``plate``   the centre of one sphere in the plate frame (``"sphere1"``, three columns per feature) [m]: constant
            (exact), or varying with its features (a loose sphere rolling with gravity; first order)
``scale``   the measurement frame's scale about its origin (``"meas_scale"``): ``p -> p (1 + delta)``
``field``   the measurement field (``"meas_field"``): ``p -> p + sum_k phi_k G_k(p)``, lens distortion, a
            scale that changes with depth, a quadratic field (:mod:`twin.diagnosis.field`; first order)
==========  =============================================================================================

Atoms come in two pools. The *catalogue* names physical effects (family from :data:`EFFECT_VOCABULARY`),
split per joint, harmonic order, link and sphere: ``compliance`` of joint ``i`` (the gravity-torque regressor
of joint ``i``, linear in the unknown mass moments), ``backlash`` of joint ``j`` (the sign of its last move),
``cyclic`` order ``k`` of joint ``j`` (``sin``/``cos(k q_j)``), ``gear_ratio`` of joint ``j`` (``q_j``),
``coupling`` (``theta6`` with ``q5``), ``thermal`` growth of each link and of all links together (against
``temp_c``, or a cubic in ``t_s``), ``plate_geometry`` per sphere. The *generic* pool (family ``unnamed``)
is the dictionary for what no catalogue holds: every joint angle, link length, twist, the tool and base
frames and the measurement scale, against low-order polynomials and harmonics of every joint, products of
two joints, approach signs, the gravity direction in the flange frame, polynomials and change points in
time (or row order), temperature, and the station.

An atom's features are read from the rows by :func:`twin.diagnosis.values.feature_values`; the two pools are
built by :mod:`twin.diagnosis.pools`. A feature is a small typed object (:mod:`twin.diagnosis.features`: ``Pow(ch="q3", p=2, c=..., h=...)``, stored as
``{"kind": "pow", "ch": "q3", "p": 2, "c": ..., "h": ...}``) whose constants (centres, scales, reference
temperature, change-point times) are fixed on the rows the atom is identified on, so that ``twin predict``
evaluates the same regressor on new rows. Nothing here reads truth.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field

from ..kinematics import RobotModel
from ..units import MM_PER_M, rad_to_deg
from .features import Const, Feature, Gated, Hinge, LoadSign, Play, Sign, Step, Window, feature_from_dict

__all__ = ["Atom", "is_load_change", "is_load_term", "PLACES", "PLAY_HALF_DEG", "BACKLASH_MOVE_WIDTHS_DEG",
           "BACKLASH_MOVE_LAWS", "BACKLASH_MOVE_REFINED_LAWS", "HINGE_POINTS", "sign_backlash", "play_backlash",
           "hinge_atom", "joint_words", "tilt_axis", "tilt_coefficient", "MIN_ROWS", "MIN_SIDE", "started_at",
           "change_from"]

MIN_ROWS = 3  # rows on each side of a step (and of a window), at least
MIN_SIDE = 0.05  # ... and this share of the rows: a state held by a handful of rows at an end is no state


PLAY_HALF_DEG = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)  # half clearances tried for a kept backlash (then refined)
# widths of the catalogue's backlash growing with the size of the joint's last move, each law's (then refined): up to
# a lag in proportion to moves of tens of degrees
BACKLASH_MOVE_WIDTHS_DEG = (2.0, 6.0, 20.0, 60.0)
BACKLASH_MOVE_LAWS = (None, "clip")  # tanh of the move over the width; in proportion up to the width
# the laws a kept one is refined over (each at its best width): the grid's and the first-order take-up,
# sign(m) (1 - exp(-|m| / w))
BACKLASH_MOVE_REFINED_LAWS = (None, "clip", "exp")
HINGE_POINTS = 9  # angles (deciles of a joint's range) past which a one-sided pull may start (then refined)
PLACES = ("joint", "length", "param", "plate", "scale", "field")


@dataclass(frozen=True, eq=False)
class Atom:
    """One candidate term: ``family`` (catalogue name or ``"unnamed"``), ``place`` and ``target`` (where it
    acts), ``features`` (``K`` features, :mod:`twin.diagnosis.features`), ``channel`` (what it depends on, for
    people), ``label`` (words), ``pool`` (``"catalogue"``/``"generic"``), and ``joints`` (1-based joints it
    involves)."""

    family: str
    place: str
    target: str
    features: tuple[Feature, ...]
    channel: str
    label: str
    pool: str
    joints: tuple[int, ...] = ()
    meta: dict = field(default_factory=dict)

    @property
    def K(self) -> int:
        if self.place == "plate":
            return 3 * len(self.features)
        if self.place == "param" and self.target in ("tool", "base"):
            return 6 * len(self.features)
        if self.place == "param" and self.target == "base_along":
            return 1
        if self.place == "param" and self.target.startswith("tilt") and \
                any(getattr(f, "shape", None) is not None for f in self.features):
            # one coefficient per shape (both axes of a moment's shape; the two halves of a cross term)
            return len({tilt_coefficient(f, k) for k, f in enumerate(self.features)})
        return len(self.features)

    @property
    def varying_plate(self) -> bool:
        """A plate atom whose offset changes from row to row (first order), not a constant one (exact)."""
        return self.place == "plate" and any(not isinstance(f, Const) for f in self.features)

    @property
    def first_order(self) -> bool:
        """Whether the atom acts on the prediction to first order (through the Jacobian), not exactly through
        the joints or a constant plate offset."""
        return self.place in ("length", "param", "scale", "field") or self.varying_plate

    @property
    def key(self) -> str:
        return f"{self.family}:{self.place}:{self.target}:{self.channel}"

    @functools.cached_property
    def feature_key(self) -> str:
        """The repr of its features, the key of their values in a problem's caches (computed once: an atom's features
        do not change)."""
        return repr(self.features)

    def spec(self) -> dict:
        """JSON-ready description (values are added by the caller)."""
        return {"family": self.family, "place": self.place, "target": self.target, "channel": self.channel,
                "label": self.label, "joints": list(self.joints), "features": [f.to_dict() for f in self.features]}

    @classmethod
    def from_spec(cls, d: dict) -> "Atom":
        for k in ("family", "place", "target", "features"):
            if k not in d:
                raise ValueError(f"effect term is missing {k!r}: {d!r}")
        if d["place"] not in PLACES:
            raise ValueError(f"effect term place {d['place']!r} is not one of {', '.join(PLACES)}")
        return cls(family=d["family"], place=d["place"], target=d["target"],
                   features=tuple(feature_from_dict(f) for f in d["features"]),
                   channel=d.get("channel", ""), label=d.get("label", ""), pool=d.get("pool", ""),
                   joints=tuple(d.get("joints", ())))


def sign_backlash(j: int, name: str | None = None) -> Atom:
    """Joint ``j``'s backlash as an offset signed by the direction of its last move (the catalogue's); ``name``: the
    joint's words in the label (default its number)."""
    return Atom("backlash", "joint", f"theta{j}", (Sign(j=j),), f"approach_sign_j{j}",
                f"joint {name or j} backlash (offset signed by the direction of its last move)", "catalogue", (j,))


def play_backlash(j: int, h: float) -> Atom:
    """Joint ``j``'s backlash as a play operator with half clearance ``h`` [rad] (moves shorter than the
    clearance do not switch the side): it competes with the sign backlash (:func:`twin.diagnosis.refine.prefer_play`)."""
    hd = rad_to_deg(h)
    return Atom("backlash", "joint", f"theta{j}", (Play(j=j, h=float(h)),), f"play j{j} half {hd:.3g} deg",
                f"joint {j} backlash with a half clearance of {hd:.3g} deg (play: short moves do not switch the side)",
                "catalogue", (j,))


def hinge_atom(j: int, at: float, side: int, p: int, h: float, *, prismatic: bool = False,
               words: str | None = None) -> Atom:
    """Joint ``j``'s angle growing as ``(max(0, side (q_j - at)) / h)^p`` [``at`` rad, ``h`` rad a scale]: zero on one
    side of the angle ``at``, a power of the overtravel past it (a cable or hose going taut and pulling). A
    prismatic joint's position likewise ([m]); ``words``: the joint in words (default ``j``)."""
    ad, unit = (at * MM_PER_M, "mm") if prismatic else (rad_to_deg(at), "deg")
    rel = f"q{j} - {ad:.4g} {unit}" if side > 0 else f"{ad:.4g} {unit} - q{j}"
    ch = f"max(0, {rel})" + ("" if p == 1 else f"^{p}")
    what = "position varies with {} (a pull past a position)" if prismatic else "angle varies with {} (a pull past an angle)"
    return Atom("unnamed", "joint", f"theta{j}", (Hinge(ch=f"q{j}", at=float(at), side=int(side),
                                                  p=int(p), h=float(h)),), ch,
                f"unnamed: joint {words or j} {what.format(ch)}", "generic", (j,))


def joint_words(model: RobotModel, j: int) -> str:
    """How a joint is named in words: ``"3"`` on the 6R robots, ``"3 (arm_2_joint)"`` on a named chain."""
    return str(j) if model.convention != "urdf" else f"{j} ({model.joint_names[j - 1]})"


def tilt_axis(f: Feature, k: int) -> int:
    """The pivot axis (0: x, 1: y) the ``k``-th feature ``f`` of a tilt atom turns: its ``about`` axis, else the axis of
    its moment, else ``k``."""
    about = getattr(f, "about", None)
    return int(about) if about is not None else int(getattr(f, "axis", k))


def tilt_coefficient(f: Feature, k: int) -> int:
    """The coefficient of a tilt atom the ``k``-th feature ``f`` goes with: its ``shape`` (features of one shape share
    one), else its own ``k``."""
    shape = getattr(f, "shape", None)
    return int(shape) if shape is not None else k


def is_load_change(atom: Atom) -> bool:
    """Whether ``atom`` is a change of a joint's compliance (its gravity-torque shapes gated in time: a payload hung
    on or taken off)."""
    return atom.family == "change" and atom.place == "joint" and bool(atom.features) \
        and isinstance(atom.features[0], Gated)


def is_load_term(a: Atom) -> bool:
    """Whether ``a`` is a term of the arm's own load: a joint's compliance (linear or stiffening), a backlash signed
    by the load, a support's tilt."""
    return ((a.family == "compliance" and a.place == "joint") or a.family == "tilt"
            or (a.family == "backlash" and bool(a.features) and isinstance(a.features[0], LoadSign)))


def started_at(atom: Atom, at: float) -> Atom:
    """The step ``atom`` (:func:`~twin.diagnosis.changes.is_step`) from ``at`` (its time channel's value) on instead."""
    return change_from(atom, float(at), atom.pool)


def change_from(atom: Atom, at: float, pool: str) -> Atom:
    """The change ``atom``'s features from ``at`` on without an end (a step, or a gated shape), its label to match,
    in ``pool``."""
    ch = atom.features[0].ch
    if isinstance(atom.features[0], (Step, Window)):
        feats = tuple(Step(ch=f.ch, at=at) for f in atom.features)
    else:
        feats = tuple(Gated(f=f.f, ch=f.ch, at=at) for f in atom.features)
    label = re.sub(r"from \S+ \S+ (on|until \S+)$", f"from {ch} {at:.6g} on", atom.label)
    return Atom(atom.family, atom.place, atom.target, feats, f"change({ch} >= {at:.6g})", label, pool, atom.joints,
                dict(atom.meta))

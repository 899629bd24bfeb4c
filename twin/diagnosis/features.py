"""Features: the functions of a row an atom's channel is built from (:mod:`twin.diagnosis.atoms`), as typed objects.

A feature is one frozen dataclass per ``kind`` (``Pow``: ``kind = "pow"``, a centred power of a channel; ``Step``: a
change point; ``Heat``: the motors' heat through a lag; ...), whose fields are its constants (centres and scales,
change-point times [s or rows], time constants [s], half clearances [rad], ...) fixed on the rows the atom is
identified on. Sequences are tuples, so a feature hashes and compares by value. :meth:`Feature.to_dict` gives the
dict ``diagnosis.json`` and ``calibration.json`` store (``{"kind": "pow", "ch": "q3", "p": 2, "c": ..., "h": ...}``:
the kind first, then the fields in order, an optional field left out while it is ``None``, tuples as lists), and
:func:`feature_from_dict` reads such a dict back. What a feature's values are on the rows is
:func:`twin.diagnosis.values.feature_values`; nothing here computes.

The optional fields keep what evaluating a term on other rows needs from its campaign
(:func:`twin.diagnosis.values.with_records`): ``record`` (a lag's or the motion heat's record of the campaign),
``record_pose_id`` (the campaign's pose ids, a term in the row order) and ``t_span`` (the campaign's time span [s]).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar

__all__ = [
    "Feature",
    "LagRecord",
    "HeatRecord",
    "Pow",
    "Sin",
    "Cos",
    "Prod",
    "Sign",
    "Grav",
    "LastMove",
    "GravMix",
    "Torque",
    "Moment",
    "BaseMoment",
    "GravityDir",
    "Step",
    "Window",
    "LoadSign",
    "Hinge",
    "StepIn",
    "Heat",
    "Settle",
    "Gated",
    "Play",
    "CartDir",
    "Exp",
    "Lag",
    "Station",
    "Const",
    "Field",
    "FEATURE_KINDS",
    "feature_from_dict",
]

# frozen, keyword-only; the repr is :class:`_Repr`'s (the dataclass' text, kept once made)
_FROZEN = dict(frozen=True, kw_only=True, repr=False)


class _Repr:
    """The repr of a frozen dataclass, the text the dataclass' own repr gives (``Kind(field=value, ...)``, every field
    in order), made once per object and kept: it is the key of a feature set's values (``repr`` of an atom's
    features), asked for every new atom, and a record or a weight vector makes it long."""

    def __repr__(self) -> str:
        got = self.__dict__.get("_repr")
        if got is None:
            inner = ", ".join(f"{fl.name}={getattr(self, fl.name)!r}" for fl in fields(self))
            got = self.__dict__["_repr"] = f"{type(self).__qualname__}({inner})"
        return got


def _plain(v: Any) -> Any:
    """``v`` as the JSON-ready value the dicts hold: tuples as lists (nested), features and records as dicts."""
    if isinstance(v, (Feature, LagRecord, HeatRecord)):
        return v.to_dict()
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _freeze(v: Any) -> Any:
    """``v`` read from a dict with its lists as tuples (nested), so the feature hashes."""
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


@dataclass(**_FROZEN)
class LagRecord(_Repr):
    """A lagged channel's record of its campaign: the row times ``t_s`` [s] and the channel values ``x``, in the
    campaign's measurement order."""

    t_s: tuple[float, ...]
    x: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"t_s": list(self.t_s), "x": list(self.x)}

    @classmethod
    def from_dict(cls, d: dict) -> "LagRecord":
        return cls(t_s=_freeze(d["t_s"]), x=_freeze(d["x"]))


@dataclass(**_FROZEN)
class HeatRecord(_Repr):
    """The motion heat's record of its campaign: row times ``t_s`` [s], commanded joints ``q`` ``(n, N)`` [rad] and
    the rows where its history restarted (``reset``), in the campaign's measurement order."""

    t_s: tuple[float, ...]
    q: tuple[tuple[float, ...], ...]
    reset: tuple[bool, ...]

    def to_dict(self) -> dict:
        return {"t_s": list(self.t_s), "q": _plain(self.q), "reset": list(self.reset)}

    @classmethod
    def from_dict(cls, d: dict) -> "HeatRecord":
        return cls(t_s=_freeze(d["t_s"]), q=_freeze(d["q"]), reset=_freeze(d["reset"]))


@dataclass(**_FROZEN)
class Feature(_Repr):
    """A feature of the rows (one subclass per ``kind``); :meth:`to_dict` / :func:`feature_from_dict` give and read
    its stored dict. Fields declared ``... | None = None`` are optional: absent from the dict while ``None``."""

    kind: ClassVar[str] = ""

    def to_dict(self) -> dict:
        """The stored dict: ``kind``, then the fields in their order (an optional one left out while ``None``)."""
        d = {"kind": self.kind}
        for fl in fields(self):
            v = getattr(self, fl.name)
            if v is None and fl.default is None:
                continue
            d[fl.name] = _plain(v)
        return d

    @classmethod
    def _read(cls, name: str, v: Any) -> Any:
        """Field ``name``'s value from the stored ``v``: a nested feature (a dict with a ``kind``) read as one, lists
        as tuples; kinds with other nested values (records, a table of times) override."""
        return feature_from_dict(v) if isinstance(v, dict) and "kind" in v else _freeze(v)

    @classmethod
    def from_dict(cls, d: dict) -> "Feature":
        names = [fl.name for fl in fields(cls)]
        extra = [k for k in d if k != "kind" and k not in names]
        if extra:
            raise ValueError(f"feature kind {cls.kind!r} has no {', '.join(map(repr, extra))} "
                             f"(its keys: {', '.join(names)})")
        need = [fl.name for fl in fields(cls) if fl.default is not None and fl.name not in d]
        if need:
            raise ValueError(f"feature kind {cls.kind!r} is missing {', '.join(map(repr, need))}: {d!r}")
        return cls(**{k: cls._read(k, v) for k, v in d.items() if k != "kind"})


# ------------------------------------------------------------------------------------------------
# Functions of the joint angles (or of any channel: ``q<j>``, ``t_s``, ``temp_c``, ``row``)
# ------------------------------------------------------------------------------------------------

@dataclass(**_FROZEN)
class Pow(Feature):
    """``((x - c) / h)^p`` of the channel ``ch`` (``c``, ``h`` in the channel's unit: rad, m, s, degC, rows)."""

    kind: ClassVar[str] = "pow"
    ch: str
    p: int
    c: float
    h: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Sin(Feature):
    """``sin(k x)`` of the channel ``ch`` (``k`` [1/unit of the channel]: cycles per joint turn, rad/s in time)."""

    kind: ClassVar[str] = "sin"
    ch: str
    k: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Cos(Feature):
    """``cos(k x)`` of the channel ``ch`` (as :class:`Sin`)."""

    kind: ClassVar[str] = "cos"
    ch: str
    k: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Prod(Feature):
    """The product ``(x_a - c_a) / h_a * (x_b - c_b) / h_b`` of the two channels ``ch = (a, b)``."""

    kind: ClassVar[str] = "prod"
    ch: tuple[str, str]
    c: tuple[float, float]
    h: tuple[float, float]


@dataclass(**_FROZEN)
class Hinge(Feature):
    """``(max(0, side (x - at)) / h)^p`` of the channel ``ch`` (``at``, ``h`` [rad, or m on a prismatic joint]):
    zero on one side of ``at``, a power of the overtravel past it (a cable going taut)."""

    kind: ClassVar[str] = "hinge"
    ch: str
    at: float
    side: int
    p: int
    h: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


# ------------------------------------------------------------------------------------------------
# The motion history (order of the rows)
# ------------------------------------------------------------------------------------------------

@dataclass(**_FROZEN)
class Sign(Feature):
    """The approach sign of joint ``j`` (1-based): the sign of its last move, 0 while unknown."""

    kind: ClassVar[str] = "sign"
    j: int


@dataclass(**_FROZEN)
class LastMove(Feature):
    """``tanh(last move of joint j / w)`` (``w`` [rad, or m on a prismatic joint]): hysteresis following the size of
    the last move; ``law`` ``"clip"``: ``clip(last move / w, -1, 1)`` instead (in proportion to the move up to ``w``,
    the full size beyond it); ``"exp"``: ``sign(m) (1 - exp(-|m| / w))`` of the last move ``m`` (taken up at a rate in
    proportion to what is left, Dahl's first-order law)."""

    kind: ClassVar[str] = "lastmove"
    j: int
    w: float
    law: str | None = None


@dataclass(**_FROZEN)
class StepIn(Feature):
    """The move [rad] of joint ``j`` into the row from the one before (0 for a repeat, after a restart)."""

    kind: ClassVar[str] = "stepin"
    j: int


@dataclass(**_FROZEN)
class Play(Feature):
    """Joint ``j``'s backlash as a play operator with half clearance ``h`` [rad], in [-1, 1]."""

    kind: ClassVar[str] = "play"
    j: int
    h: float


@dataclass(**_FROZEN)
class CartDir(Feature):
    """Component ``axis`` (0-2) of the unit direction of the last Cartesian move of the point ``tcp`` (flange frame
    [m]; the flange's origin when absent) in the base frame."""

    kind: ClassVar[str] = "cartdir"
    axis: int
    tcp: tuple[float, float, float] | None = None


# ------------------------------------------------------------------------------------------------
# Gravity
# ------------------------------------------------------------------------------------------------

@dataclass(**_FROZEN)
class Grav(Feature):
    """One column of the gravity-torque regressor: joint ``i``'s torque from link ``k``'s mass moment component
    ``c`` (0: mass, 1-3: first moments), over ``h`` (1 when absent)."""

    kind: ClassVar[str] = "grav"
    i: int
    k: int
    c: int
    h: float | None = None


@dataclass(**_FROZEN)
class GravMix(Feature):
    """Joint ``i``'s gravity torque as the combination ``w`` of the regressor columns ``cols`` (``(k, c)`` pairs),
    over ``h``: a principal torque shape under the generic prior on the mass moments."""

    kind: ClassVar[str] = "gravmix"
    i: int
    cols: tuple[tuple[int, int], ...]
    w: tuple[float, ...]
    h: float


@dataclass(**_FROZEN)
class Torque(Feature):
    """Joint ``j``'s gravity load from the chain's mass properties [N m, or N along a prismatic axis], over ``h``
    (1 when absent)."""

    kind: ClassVar[str] = "torque"
    j: int
    h: float | None = None


@dataclass(**_FROZEN)
class Moment(Feature):
    """Component ``axis`` of the gravity moment [N m] of what joint ``j`` carries (``j = 0``: the base), in its frame,
    over ``h`` (1 when absent). In a tilt it turns the pivot about its ``about`` axis (``axis`` when absent: a
    compliance per axis; the other: the cross term of a compliance whose principal axes are turned), with the
    coefficient of ``shape`` (its own when absent)."""

    kind: ClassVar[str] = "moment"
    j: int
    axis: int
    h: float | None = None
    about: int | None = None
    shape: int | None = None


@dataclass(**_FROZEN)
class BaseMoment(Feature):
    """The arm's gravity moment about the base's horizontal axis ``axis`` as the combination ``w`` of the links'
    unknown mass moments (principal shape ``shape``: the coefficient it shares), over ``h`` (1 when absent); in a
    tilt it turns the base about its ``about`` axis (``axis`` when absent)."""

    kind: ClassVar[str] = "basemoment"
    axis: int
    shape: int
    w: tuple[float, ...]
    h: float | None = None
    about: int | None = None


@dataclass(**_FROZEN)
class GravityDir(Feature):
    """Component ``axis`` (0-2) of the unit gravity direction in the flange frame."""

    kind: ClassVar[str] = "gdir"
    axis: int


@dataclass(**_FROZEN)
class LoadSign(Feature):
    """The sign of the gravity load feature ``f`` (a :class:`Torque` or a :class:`GravMix`); ``u``: the direction
    in the span of the joint's torque shapes it was built from (refined when kept); ``width``: a smooth flank,
    ``tanh(f / width)`` instead of the sign (``width`` in the unit of ``f``'s values); ``law`` ``"clip"``:
    ``clip(f / width, -1, 1)`` instead (in proportion up to the width, constant beyond)."""

    kind: ClassVar[str] = "loadsign"
    f: Feature
    u: tuple[float, ...] | None = None
    width: float | None = None
    law: str | None = None


# ------------------------------------------------------------------------------------------------
# Time, temperature, station
# ------------------------------------------------------------------------------------------------

@dataclass(**_FROZEN)
class Step(Feature):
    """``1[x >= at]`` of the channel ``ch`` (``t_s`` [s] or ``row``): a change point."""

    kind: ClassVar[str] = "step"
    ch: str
    at: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Window(Feature):
    """``1[at <= x < until]`` of the channel ``ch``: a change and back."""

    kind: ClassVar[str] = "window"
    ch: str
    at: float
    until: float
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Gated(Feature):
    """The feature ``f`` from ``x >= at`` on (until ``x < until`` when given) of the channel ``ch``: a payload added
    at a restart."""

    kind: ClassVar[str] = "gated"
    f: Feature
    ch: str
    at: float
    until: float | None = None
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Exp(Feature):
    """``1 - exp(-(x - t0) / tau)`` of the channel ``ch`` (zero before ``t0``; ``t0``, ``tau`` [s]): a warm-up, the
    response of a first-order lag to a unit step of its input at ``t0``. With ``ramp`` [s], the response to a unit
    ramp of the input from ``t0`` over ``ramp`` (the air warming over that time): ``u / T - (tau / T) (1 - e^{-u /
    tau})`` while ``u = x - t0 <= T``, ``1 - (tau / T) (e^{-(u - T) / tau} - e^{-u / tau})`` after."""

    kind: ClassVar[str] = "exp"
    ch: str
    t0: float
    tau: float
    ramp: float | None = None
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None


@dataclass(**_FROZEN)
class Lag(Feature):
    """``(y - c) / h`` of the channel ``ch`` (``temp_c``) seen through a first-order lag of time constant ``tau``
    [s] (``h`` 1 when absent); ``record``: the campaign's record it continues. ``gap``: where in each interval between
    recorded rows the channel changes from one row's value to the next, as a fraction of the interval (a step there;
    absent: linear between the rows): a change of the air in a pause or a station change is not timed by a record
    taken at the rows."""

    kind: ClassVar[str] = "lag"
    ch: str
    tau: float
    c: float
    h: float | None = None
    gap: float | None = None
    record: LagRecord | None = None
    record_pose_id: tuple[int, ...] | None = None
    t_span: tuple[float, float] | None = None

    @classmethod
    def _read(cls, name: str, v: Any) -> Any:
        return LagRecord.from_dict(v) if name == "record" else _freeze(v)


@dataclass(**_FROZEN)
class Heat(Feature):
    """The heat [rad of joint travel] the motors of ``joints`` (1-based; all when absent) put into the arm, through a
    first-order lag of time constant ``tau`` [s], over ``h``; ``record``: the campaign's record it continues."""

    kind: ClassVar[str] = "heat"
    tau: float
    joints: tuple[int, ...] | None = None
    h: float
    record: HeatRecord | None = None

    @classmethod
    def _read(cls, name: str, v: Any) -> Any:
        return HeatRecord.from_dict(v) if name == "record" else _freeze(v)


@dataclass(**_FROZEN)
class Settle(Feature):
    """``1 - exp(-(t_s - t0[station]) / tau)``: a station's instrument settling after it was set up (``t0``: each
    station's set-up time [s], as ``(station, t0)`` pairs; ``tau`` [s]); on station ``only``'s rows alone when
    given."""

    kind: ClassVar[str] = "settle"
    tau: float
    t0: tuple[tuple[str, float], ...]
    only: str | None = None
    t_span: tuple[float, float] | None = None

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["t0"] = dict(self.t0)
        return d

    @classmethod
    def _read(cls, name: str, v: Any) -> Any:
        return tuple(v.items()) if name == "t0" else _freeze(v)


@dataclass(**_FROZEN)
class Station(Feature):
    """``1`` on the rows of station ``name``, else 0."""

    kind: ClassVar[str] = "station"
    name: str


@dataclass(**_FROZEN)
class Const(Feature):
    """``1`` on every row: a constant."""

    kind: ClassVar[str] = "const"


@dataclass(**_FROZEN)
class Field(Feature):
    """A measurement field ``G_g(p)`` (:mod:`twin.diagnosis.field`) with the measured points' centring and scales
    (``z_c``, ``z_h``, ``r_c``, ``r_h`` [m], ``rho2_h``); ``n_tool``: the plate normal in the plate frame (the view
    fields); ``station``: that station's rows alone; ``t0``, ``tau`` [s]: growing as the instrument warms up."""

    kind: ClassVar[str] = "field"
    g: str
    z_c: float
    z_h: float
    r_c: float
    r_h: float
    rho2_h: float
    n_tool: tuple[float, float, float] | None = None
    station: str | None = None
    t0: float | None = None
    tau: float | None = None
    t_span: tuple[float, float] | None = None


FEATURE_KINDS: dict[str, type[Feature]] = {c.kind: c for c in (
    Pow, Sin, Cos, Prod, Sign, Grav, LastMove, GravMix, Torque, Moment, BaseMoment, GravityDir, Step, Window, LoadSign,
    Hinge, StepIn, Heat, Settle, Gated, Play, CartDir, Exp, Lag, Station, Const, Field)}


def feature_from_dict(d: dict | Feature) -> Feature:
    """The feature a stored dict describes (:meth:`Feature.to_dict` read back; a feature is returned as it is).
    ``ValueError`` naming the kind for an unknown kind, or a key the kind does not have or lacks."""
    if isinstance(d, Feature):
        return d
    if not isinstance(d, dict):
        raise ValueError(f"a feature is a table with a 'kind', got {d!r}")
    kind = d.get("kind")
    cls = FEATURE_KINDS.get(kind)
    if cls is None:
        raise ValueError(f"unknown feature kind {kind!r} in {d!r} (known: {', '.join(FEATURE_KINDS)})")
    return cls.from_dict(d)

"""Non-geometric effects of the world: the plug-in interface and the measurement context.

An effect changes what the robot *actually* does, or how the scene and the image form, given the
measurement context. Four hooks, identity by default (:class:`BaseEffect`):

* ``joints(q, context) -> q``: commanded (or the previous effect's) joints ``(6,)`` [rad] -> actual joints;
* ``geometry(robot, context) -> robot``: the robot's actual link geometry for this measurement (e.g.
  thermal growth); the world moves the MuJoCo bodies accordingly;
* ``scene(state, context) -> state``: what the scene looks like beyond the robot's pose
  (:class:`SceneState`: the sphere shapes), e.g. a sphere slightly out of round;
* ``image(img, context, camera) -> img``: the ideal greyscale image ``(H, W)`` uint8 of ``camera``
  (``"left"``/``"right"``) before distortion and noise.

Per measurement the world runs, in the order the effects are given: every ``geometry`` hook (the true
model for this pose is put into MuJoCo), then every ``joints`` hook
(``q_actual = e_n.joints(... e_1.joints(q_cmd, ctx) ..., ctx)``; a joint effect that needs MuJoCo, such as
compliance, therefore sees the geometry of this pose), then ``scene`` and, while rendering, ``image``.
A plain callable ``f(q, context) -> q`` is accepted as a joint effect (:func:`as_effect`). Each effect
describes itself (``name``, ``params()``) for the truth file; nothing about it reaches the dataset.

The built-in catalogue (compliance, backlash, cyclic, gear_ratio, coupling, thermal, sphere_out_of_round)
and the registry that builds effects from config tables live in :mod:`twin.world.effects_catalogue`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from ..kinematics import N_JOINTS, RobotModel

__all__ = [
    "EffectContext",
    "SceneState",
    "JointEffectFn",
    "Effect",
    "BaseEffect",
    "FunctionJointEffect",
    "ConstantJointOffset",
    "as_effect",
    "apply_joint_effects",
    "apply_geometry_effects",
    "apply_scene_effects",
    "contexts_for_sequence",
]


def _joint_vector(v: Any, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (N_JOINTS,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be {N_JOINTS} finite joint angles [rad], got {v!r}")
    return a


@dataclass(frozen=True)
class EffectContext:
    """What an effect may depend on at one measurement (SI).

    * ``t_s`` [s] since the campaign started; ``temp_c`` [°C] the robot's temperature (a world with a
      temperature profile, e.g. a ``thermal`` effect in warm-up mode, sets it from ``t_s``: the world's
      temperature is truth; a caller's value is used only when no effect defines the temperature);
    * ``pose_index`` (0-based, in measurement order); ``station`` index;
    * ``q_cmd`` ``(6,)`` [rad]: this measurement's command (filled by :func:`apply_joint_effects`);
    * ``q_cmd_history`` ``(k, 6)`` [rad]: every command measured *before* this one since the campaign
      started, oldest first (history-dependent effects such as backlash read the approach direction from
      it); ``q_start`` ``(6,)`` [rad]: where the campaign started (``None``: home, all zeros);
    * ``q_cmd_prev`` / ``q_actual_prev`` ``(6,)`` [rad] of the previous measurement (``q_cmd_prev`` is
      ``q_cmd_history[-1]`` when the history is given);
    * ``world``: the :class:`twin.world.World` itself, for effects that need MuJoCo (gravity statics).

    The world fills ``world``, ``q_cmd``, the history and the previous configuration from its own record
    when the caller leaves them ``None`` (see :meth:`twin.world.World.capture`). Campaigns spread over
    processes build the context from their plan instead (:func:`contexts_for_sequence`), so that an
    effect's value at a pose depends on the plan alone and a resumed campaign reproduces it. The arrays
    are not copied: do not modify them afterwards.
    """

    t_s: float = 0.0
    temp_c: float = 20.0
    pose_index: int = 0
    station: int = 0
    q_cmd_prev: np.ndarray | None = field(default=None, compare=False)
    q_actual_prev: np.ndarray | None = field(default=None, compare=False)
    world: Any = field(default=None, repr=False, compare=False)
    q_cmd: np.ndarray | None = field(default=None, compare=False)
    q_cmd_history: np.ndarray | None = field(default=None, repr=False, compare=False)
    q_start: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for name in ("t_s", "temp_c"):
            v = getattr(self, name)
            try:
                x = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"EffectContext.{name} must be a number, got {v!r}") from None
            if not np.isfinite(x):
                raise ValueError(f"EffectContext.{name} must be finite, got {v!r}")
            object.__setattr__(self, name, x)
        for name in ("q_cmd_prev", "q_actual_prev", "q_cmd", "q_start"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _joint_vector(v, f"EffectContext.{name}"))
        h = self.q_cmd_history
        if h is not None:
            h = np.asarray(h, dtype=float)
            if h.size == 0:
                h = h.reshape(0, N_JOINTS)
            if h.ndim != 2 or h.shape[1] != N_JOINTS or not np.all(np.isfinite(h)):
                raise ValueError(f"EffectContext.q_cmd_history must be (k, {N_JOINTS}) finite angles [rad], "
                                 f"got shape {h.shape}")
            object.__setattr__(self, "q_cmd_history", h)
            if len(h):
                if self.q_cmd_prev is None:
                    object.__setattr__(self, "q_cmd_prev", h[-1])
                elif np.max(np.abs(self.q_cmd_prev - h[-1])) > 1e-12:
                    raise ValueError("EffectContext: q_cmd_prev differs from q_cmd_history[-1] "
                                     f"({self.q_cmd_prev!r} vs {h[-1]!r})")
            elif self.q_cmd_prev is not None:
                raise ValueError("EffectContext: q_cmd_history is empty (first pose) but q_cmd_prev is given")

    def with_(self, **kw) -> "EffectContext":
        return replace(self, **kw)

    def command_sequence(self) -> np.ndarray | None:
        """``(k + 2, 6)`` [rad]: the start configuration, the commands before this one, and this one
        (``None`` when the history is unknown: a previous command is given without ``q_cmd_history``)."""
        if self.q_cmd is None:
            raise ValueError("EffectContext.q_cmd is not set (apply_joint_effects fills it)")
        if self.q_cmd_history is None:
            if self.q_cmd_prev is not None:
                return None
            hist = np.zeros((0, N_JOINTS))
        else:
            hist = self.q_cmd_history
        start = np.zeros(N_JOINTS) if self.q_start is None else self.q_start
        return np.vstack([start[None], hist, self.q_cmd[None]])


def contexts_for_sequence(
    q_cmd: np.ndarray,
    *,
    t_s: Sequence[float] | np.ndarray | None = None,
    temp_c: Sequence[float] | np.ndarray | None = None,
    stations: Sequence[int] | None = None,
    q_start: np.ndarray | None = None,
    world: Any = None,
) -> list[EffectContext]:
    """The effect context of every pose of a campaign measured in the order of ``q_cmd`` ``(n, 6)`` [rad].

    Context ``k`` has ``pose_index = k``, ``q_cmd = q_cmd[k]``, ``q_cmd_history = q_cmd[:k]`` (a read-only
    view of one private copy), ``q_start`` (home when ``None``), ``t_s[k]`` [s] (0 when ``None``),
    ``temp_c[k]`` [°C] (20 when ``None``; ignored by a world with a temperature profile), ``stations[k]``.
    Pure: the same plan gives the same contexts in any process.
    """
    q = np.array(q_cmd, dtype=float)
    if q.ndim != 2 or q.shape[1] != N_JOINTS or not np.all(np.isfinite(q)):
        raise ValueError(f"q_cmd must be (n, {N_JOINTS}) finite angles [rad], got shape {q.shape}")
    q.setflags(write=False)
    n = len(q)

    def column(v, name, default):
        if v is None:
            return np.full(n, default, dtype=float)
        a = np.asarray(v, dtype=float).reshape(-1)
        if a.shape != (n,):
            raise ValueError(f"{name} must have {n} entries (one per pose), got {a.shape}")
        return a

    ts = column(t_s, "t_s", 0.0)
    tc = column(temp_c, "temp_c", 20.0)
    st = [0] * n if stations is None else [int(s) for s in stations]
    if len(st) != n:
        raise ValueError(f"stations must have {n} entries (one per pose), got {len(st)}")
    start = None if q_start is None else _joint_vector(q_start, "q_start")
    return [
        EffectContext(t_s=ts[k], temp_c=tc[k], pose_index=k, station=st[k], q_cmd=q[k], q_cmd_history=q[:k],
                      q_start=start, world=world)
        for k in range(n)
    ]


@dataclass(frozen=True)
class SceneState:
    """What ``scene`` hooks may change, per measurement (SI).

    ``sphere_semi_axes`` ``(3, 3)`` [m]: row ``k`` holds sphere ``k``'s semi-axes along the plate (tool)
    frame's x, y, z; a perfect sphere has three equal entries (its radius). Its centre stays the sphere's
    true centre (the truth's sphere position).
    """

    sphere_semi_axes: np.ndarray

    def __post_init__(self) -> None:
        a = np.array(self.sphere_semi_axes, dtype=float)
        if a.shape != (3, 3) or not np.all(np.isfinite(a)) or np.any(a <= 0):
            raise ValueError(f"sphere_semi_axes must be a (3, 3) array of positive lengths [m], got {a!r}")
        a.setflags(write=False)
        object.__setattr__(self, "sphere_semi_axes", a)

    def with_(self, **kw) -> "SceneState":
        return replace(self, **kw)


JointEffectFn = Callable[[np.ndarray, EffectContext], np.ndarray]


@runtime_checkable
class Effect(Protocol):
    """The effect protocol (any object with these members; subclass :class:`BaseEffect` for defaults).

    ``scene`` is optional (looked up with ``getattr``), so objects written before it existed still fit.
    """

    name: str

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray: ...

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel: ...

    def image(self, img: np.ndarray, context: EffectContext, camera: str) -> np.ndarray: ...

    def params(self) -> dict: ...


class BaseEffect:
    """Identity in every hook; subclasses override what they change."""

    name = "identity"

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return q

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel:
        return robot

    def scene(self, state: SceneState, context: EffectContext) -> SceneState:
        return state

    def image(self, img: np.ndarray, context: EffectContext, camera: str) -> np.ndarray:
        return img

    def params(self) -> dict:
        return {}

    # which hooks this effect overrides (the world skips the costly ones otherwise)
    @property
    def changes_geometry(self) -> bool:
        return type(self).geometry is not BaseEffect.geometry

    @property
    def changes_scene(self) -> bool:
        return type(self).scene is not BaseEffect.scene

    @property
    def changes_image(self) -> bool:
        return type(self).image is not BaseEffect.image

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params()!r})"


class FunctionJointEffect(BaseEffect):
    """A plain ``f(q, context) -> q`` as an effect."""

    def __init__(self, fn: JointEffectFn, name: str | None = None):
        if not callable(fn):
            raise ValueError(f"fn must be callable f(q, context) -> q, got {fn!r}")
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "joint_function")

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return self.fn(q, context)

    def params(self) -> dict:
        module = getattr(self.fn, "__module__", None)
        qual = getattr(self.fn, "__qualname__", repr(self.fn))
        return {"function": f"{module}:{qual}" if module else qual}


class ConstantJointOffset(BaseEffect):
    """The trivial example: every joint lands at ``q + offsets`` (``offsets`` ``(6,)`` [rad])."""

    name = "constant_joint_offset"

    def __init__(self, offsets: Sequence[float] | np.ndarray):
        o = np.asarray(offsets, dtype=float).reshape(-1)
        if o.shape != (N_JOINTS,) or not np.all(np.isfinite(o)):
            raise ValueError(f"offsets must be {N_JOINTS} finite numbers [rad], got {offsets!r}")
        self.offsets = o

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return q + self.offsets

    def params(self) -> dict:
        return {"offsets_rad": self.offsets.tolist()}


def as_effect(obj: Any) -> BaseEffect | Effect:
    """An effect object as is; a plain callable becomes a :class:`FunctionJointEffect`."""
    if isinstance(obj, Effect):
        return obj
    if callable(obj):
        return FunctionJointEffect(obj)
    raise ValueError(f"effect must be an Effect or a callable f(q, context) -> q, got {obj!r}")


def _effect_name(e: Any) -> str:
    return str(getattr(e, "name", type(e).__name__))


def apply_joint_effects(effects: Sequence[Effect], q_cmd: np.ndarray, context: EffectContext) -> np.ndarray:
    """``q_actual`` ``(6,)`` [rad]: the joint hooks of ``effects`` in order, starting from ``q_cmd``.

    The context's ``q_cmd`` is set to ``q_cmd`` when it is ``None`` (and must equal it otherwise).
    """
    q = _joint_vector(np.asarray(q_cmd, dtype=float).reshape(-1), "q_cmd").copy()
    if context.q_cmd is None:
        context = context.with_(q_cmd=q.copy())
    elif np.max(np.abs(context.q_cmd - q)) > 1e-12:
        raise ValueError(f"context.q_cmd {context.q_cmd!r} differs from q_cmd {q!r}")
    for e in effects:
        out = np.asarray(e.joints(q.copy(), context), dtype=float).reshape(-1)
        if out.shape != (N_JOINTS,) or not np.all(np.isfinite(out)):
            raise ValueError(f"effect {_effect_name(e)!r} returned {out!r}; expected {N_JOINTS} finite angles [rad]")
        q = out
    return q


def apply_geometry_effects(effects: Sequence[Effect], robot: RobotModel, context: EffectContext) -> RobotModel:
    """The actual robot for this measurement: the geometry hooks of ``effects`` in order (``robot`` itself
    when none changes it)."""
    for e in effects:
        if getattr(e, "changes_geometry", True):
            out = e.geometry(robot, context)
            if not isinstance(out, RobotModel):
                raise ValueError(f"effect {_effect_name(e)!r}: geometry() must return a RobotModel, got {out!r}")
            if out.convention != robot.convention or out.beta_joints != robot.beta_joints:
                raise ValueError(f"effect {_effect_name(e)!r}: geometry() changed the model's structure")
            robot = out
    return robot


def apply_scene_effects(effects: Sequence[Effect], state: SceneState, context: EffectContext) -> SceneState:
    """The scene for this measurement: the ``scene`` hooks of ``effects`` in order."""
    for e in effects:
        hook = getattr(e, "scene", None)
        if hook is not None and getattr(e, "changes_scene", True):
            out = hook(state, context)
            if not isinstance(out, SceneState):
                raise ValueError(f"effect {_effect_name(e)!r}: scene() must return a SceneState, got {out!r}")
            state = out
    return state

"""Non-geometric effects of the world: the plug-in interface (the catalogue comes with close-the-loop).

An effect changes what the robot *actually* does or how the image forms, given the measurement context:

* ``joints(q, context) -> q``: commanded (or the previous effect's) joints ``(6,)`` [rad] -> actual joints;
* ``geometry(robot, context) -> robot``: the robot's actual link geometry for this measurement (e.g.
  thermal growth); the world moves the MuJoCo bodies accordingly;
* ``image(img, context, camera) -> img``: the ideal greyscale image ``(H, W)`` uint8 of ``camera``
  (``"left"``/``"right"``) before distortion and noise.

Effects run in the order given: ``q_actual = e_n.joints(... e_1.joints(q_cmd, ctx) ..., ctx)``. A plain
callable ``f(q, context) -> q`` is accepted as a joint effect (:func:`as_effect`). Each effect describes
itself (``name``, ``params()``) for the truth file.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from ..kinematics import N_JOINTS, RobotModel

__all__ = [
    "EffectContext",
    "JointEffectFn",
    "Effect",
    "FunctionJointEffect",
    "ConstantJointOffset",
    "as_effect",
    "apply_joint_effects",
    "effect_from_spec",
    "EFFECT_TYPES",
]


@dataclass(frozen=True)
class EffectContext:
    """What an effect may depend on at one measurement.

    ``t_s`` [s] since the campaign started; ``temp_c`` [°C]; ``pose_index`` (0-based, measurement order);
    ``station`` index; ``q_cmd_prev`` / ``q_actual_prev`` ``(6,)`` [rad] of the previous measurement
    (``None`` at the first: history-dependent effects such as backlash use the approach direction);
    ``world``: the :class:`twin.world.World` itself, for effects that need MuJoCo (gravity statics).
    The world fills ``q_*_prev`` and ``world`` from its own history when the caller leaves them ``None``.
    """

    t_s: float = 0.0
    temp_c: float = 20.0
    pose_index: int = 0
    station: int = 0
    q_cmd_prev: np.ndarray | None = None
    q_actual_prev: np.ndarray | None = None
    world: Any = field(default=None, repr=False, compare=False)

    def with_(self, **kw) -> "EffectContext":
        return replace(self, **kw)


JointEffectFn = Callable[[np.ndarray, EffectContext], np.ndarray]


@runtime_checkable
class Effect(Protocol):
    """The effect protocol (any object with these members; subclass :class:`BaseEffect` for defaults)."""

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

    def image(self, img: np.ndarray, context: EffectContext, camera: str) -> np.ndarray:
        return img

    def params(self) -> dict:
        return {}

    # which hooks this effect overrides (the world skips the costly ones otherwise)
    @property
    def changes_geometry(self) -> bool:
        return type(self).geometry is not BaseEffect.geometry

    @property
    def changes_image(self) -> bool:
        return type(self).image is not BaseEffect.image


__all__.append("BaseEffect")


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
        return {"function": getattr(self.fn, "__qualname__", repr(self.fn))}


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


def apply_joint_effects(effects: Sequence[Effect], q_cmd: np.ndarray, context: EffectContext) -> np.ndarray:
    """``q_actual`` ``(6,)`` [rad]: the joint hooks of ``effects`` in order, starting from ``q_cmd``."""
    q = np.asarray(q_cmd, dtype=float).reshape(-1).copy()
    if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
        raise ValueError(f"q_cmd must be {N_JOINTS} finite joint angles [rad], got {q_cmd!r}")
    for e in effects:
        out = np.asarray(e.joints(q.copy(), context), dtype=float).reshape(-1)
        if out.shape != (N_JOINTS,) or not np.all(np.isfinite(out)):
            raise ValueError(f"effect {getattr(e, 'name', e)!r} returned {out!r}; expected {N_JOINTS} finite angles [rad]")
        q = out
    return q


EFFECT_TYPES: dict[str, Callable[[Mapping[str, Any]], BaseEffect]] = {
    "constant_joint_offset": lambda spec: ConstantJointOffset(np.deg2rad(np.asarray(spec["offsets_deg"], dtype=float))),
}


def effect_from_spec(spec: Mapping[str, Any]) -> BaseEffect:
    """An effect from a config table: ``{type = "constant_joint_offset", offsets_deg = [...]}``."""
    t = spec.get("type")
    if t not in EFFECT_TYPES:
        raise ValueError(f"world.effects: unknown effect type {t!r}; known: {', '.join(sorted(EFFECT_TYPES))}")
    try:
        return EFFECT_TYPES[t](spec)
    except KeyError as exc:
        raise ValueError(f"world.effects ({t}): missing field {exc}") from None

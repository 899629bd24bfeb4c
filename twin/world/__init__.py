"""The world: MuJoCo twin of the robot, plate, stereo rig and calibration board (the truth side).

Commanded joints in, rendered 8-bit greyscale stereo images out; the truth goes only to ``truth.json``
(read by evaluation). See ``docs/world.md``.
"""

import os as _os

_os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported anywhere below

from .config import (  # noqa: E402
    BoardConfig,
    PlateConfig,
    RenderConfig,
    RigConfig,
    StationConfig,
    WorldConfig,
    default_stations,
    load_world_config,
)
from .effects import (  # noqa: E402
    BaseEffect,
    ConstantJointOffset,
    Effect,
    EffectContext,
    SceneState,
    as_effect,
    contexts_for_sequence,
)
from .effects_catalogue import (  # noqa: E402
    EFFECT_TYPES,
    Backlash,
    Compliance,
    Coupling,
    CyclicError,
    GearRatio,
    SphereOutOfRound,
    ThermalGrowth,
    effect_from_spec,
    register_effect,
)
from .world import BoardView, Capture, World  # noqa: E402

__all__ = [
    "World",
    "Capture",
    "BoardView",
    "WorldConfig",
    "StationConfig",
    "RigConfig",
    "RenderConfig",
    "BoardConfig",
    "PlateConfig",
    "default_stations",
    "load_world_config",
    "Effect",
    "BaseEffect",
    "EffectContext",
    "ConstantJointOffset",
    "SceneState",
    "as_effect",
    "contexts_for_sequence",
    "EFFECT_TYPES",
    "Backlash",
    "Compliance",
    "Coupling",
    "CyclicError",
    "GearRatio",
    "SphereOutOfRound",
    "ThermalGrowth",
    "effect_from_spec",
    "register_effect",
]

"""The world: MuJoCo twin of the robot, plate, stereo rig and calibration board (the truth side).

Commanded joints in, rendered 8-bit greyscale stereo images out; the truth goes only to ``truth.json``
(read by evaluation). See ``docs/world.md``.
"""

from .config import (
    BoardConfig,
    PlateConfig,
    RenderConfig,
    RigConfig,
    StationConfig,
    WorldConfig,
    default_stations,
    load_world_config,
)
from .effects import (
    BaseEffect,
    ConstantJointOffset,
    Effect,
    EffectContext,
    SceneState,
    as_effect,
    contexts_for_sequence,
)
from .effects_catalogue import (
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
from .world import BoardView, Capture, World

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

"""Effects: the commanded -> actual interface, its context, and how the world applies it."""

import numpy as np
import pytest

from twin.world.effects import (
    BaseEffect,
    ConstantJointOffset,
    EffectContext,
    apply_joint_effects,
    as_effect,
    effect_from_spec,
)


def test_constant_offset_moves_every_joint():
    """The example effect returns q + offsets."""
    e = ConstantJointOffset([0.01, -0.02, 0, 0, 0.003, 0])
    q = np.linspace(-1, 1, 6)
    assert np.allclose(e.joints(q, EffectContext()), q + e.offsets)


def test_effects_apply_in_order():
    """Joint effects compose in the order given (a scale after an offset differs from the reverse)."""
    off = ConstantJointOffset(np.full(6, 0.1))
    scale = as_effect(lambda q, ctx: 2.0 * q)
    q = np.zeros(6)
    assert np.allclose(apply_joint_effects([off, scale], q, EffectContext()), 0.2)
    assert np.allclose(apply_joint_effects([scale, off], q, EffectContext()), 0.1)


def test_effect_returning_nan_is_refused():
    """An effect that returns non-finite joints is an error naming it, not a silent NaN."""
    bad = as_effect(lambda q, ctx: q * np.nan)
    with pytest.raises(ValueError, match="finite"):
        apply_joint_effects([bad], np.zeros(6), EffectContext())


def test_effect_from_config_spec():
    """A config table builds the effect, degrees at the edge."""
    e = effect_from_spec({"type": "constant_joint_offset", "offsets_deg": [1, 0, 0, 0, 0, 0]})
    assert e.offsets[0] == pytest.approx(np.deg2rad(1))
    with pytest.raises(ValueError, match="unknown effect type"):
        effect_from_spec({"type": "warp_drive"})


class _Recorder(BaseEffect):
    name = "recorder"

    def __init__(self):
        self.seen = []

    def joints(self, q, context):
        self.seen.append(context)
        return q


@pytest.fixture(scope="module")
def small_world():
    from twin.world import World

    w = World.from_config({"render": {"scale": 0.25}, "board": {"texture_px_per_square": 64}, "stations": [
        {"name": "front", "target_mm": [500, 0, 550], "elevation_deg": 5}]})
    yield w
    w.close()


def test_world_truth_uses_the_actual_joints(small_world):
    """With a joint offset the recorded actual joints and true spheres follow q_cmd + offset, not q_cmd."""
    w = small_world
    off = ConstantJointOffset([0.0, 0.002, -0.001, 0.0, 0.0, 0.0])
    w.effects = [off]
    try:
        q = w.visible_configurations(0, 1, seed=1)[0]
        cap = w.capture(q, 0, record=False)
        assert np.allclose(cap.q_actual, q + off.offsets)
        assert np.allclose(cap.spheres_meas, w.true_spheres_meas(q + off.offsets, 0), atol=1e-12)
        assert np.linalg.norm(cap.spheres_meas - w.true_spheres_meas(q, 0)) > 1e-4
    finally:
        w.effects = []


def test_world_fills_the_previous_configuration(small_world):
    """The context an effect sees carries the previous commanded and actual joints and the world."""
    w = small_world
    rec = _Recorder()
    w.effects = [rec]
    try:
        qs = w.visible_configurations(0, 2, seed=2)
        w.capture(qs[0], 0, EffectContext(t_s=1.0, temp_c=25.0), record=False)
        w.capture(qs[1], 0, EffectContext(t_s=2.0, temp_c=26.0), record=False)
        assert rec.seen[1].world is w and rec.seen[1].t_s == 2.0 and rec.seen[1].temp_c == 26.0
        assert np.allclose(rec.seen[1].q_cmd_prev, qs[0]) and np.allclose(rec.seen[1].q_actual_prev, qs[0])
    finally:
        w.effects = []


def test_geometry_effect_moves_the_mujoco_chain(small_world):
    """A geometry effect (here d4 + 0.1 mm) moves the rendered/true plate exactly as the numpy FK says."""
    from twin.kinematics import tool2meas

    class Grow(BaseEffect):
        name = "grow_d4"

        def geometry(self, robot, context):
            return robot.perturbed({"d4": 1e-4})

    w = small_world
    w.effects = [Grow()]
    try:
        q = w.visible_configurations(0, 1, seed=3)[0]
        cap = w.capture(q, 0, record=False)
        grown = w.true_robot.perturbed({"d4": 1e-4}).with_frames(base2meas=w.true_base2meas(0))
        assert np.allclose(cap.tool2meas, tool2meas(grown, q)[0], atol=1e-12)
        assert cap.params is not None
    finally:
        w.effects = []
        w._apply_geometry(w.true_robot)

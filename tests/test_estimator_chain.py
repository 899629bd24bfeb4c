"""The estimator's batched chain evaluator against the foundation's FK and pose Jacobian."""

import numpy as np
import pytest

from twin.kinematics import pose_jacobian, tool2base, tool2meas
from twin.robots import brtirus0707a, irb1200
from twin.estimator.chain import Chain


def _perturbed(make, rng):
    m = make()
    dev = rng.normal(0, 1e-2, m.layout.size)
    dev[m.layout.base_slice] = rng.normal(0, 0.5, 6)
    dev[m.layout.tool_slice] = rng.normal(0, 0.3, 6)
    return m.perturbed(dev)


def _reorder(J, m):
    """Foundation columns (rt with base in the middle) -> chain columns (base last)."""
    bs = m.layout.base_slice
    return np.concatenate([J[..., : bs.start], J[..., bs.stop:], J[..., bs]], axis=-1)


@pytest.mark.parametrize("make", [irb1200, brtirus0707a])
def test_chain_matches_foundation_in_measurement_frame(make):
    """Poses and the 37-column Jacobian equal tool2meas / pose_jacobian to 1e-13 for perturbed models."""
    rng = np.random.default_rng(1)
    m = _perturbed(make, rng)
    q = rng.uniform(-3, 3, (40, 6))
    ch = Chain(m.convention, m.beta_joints)
    rt, base = ch.split_full(m.params)
    ev = ch.evaluate(rt, q, base6=base)
    T = tool2meas(m, q)
    assert np.abs(ev.R[0] - T[:, :3, :3]).max() < 1e-13
    assert np.abs(ev.p[0] - T[:, :3, 3]).max() < 1e-13
    assert np.abs(ev.rows()[0] - _reorder(pose_jacobian(m, q), m)).max() < 1e-13


@pytest.mark.parametrize("make", [irb1200, brtirus0707a])
def test_chain_base_frame_matches_foundation(make):
    """Without a base the chain gives tool2base and the base-frame Jacobian (robot and tool columns)."""
    rng = np.random.default_rng(2)
    m = _perturbed(make, rng)
    q = rng.uniform(-3, 3, (25, 6))
    ch = Chain(m.convention, m.beta_joints)
    rt, _ = ch.split_full(m.params)
    ev = ch.evaluate(rt, q)
    T = tool2base(m, q)
    assert np.abs(ev.p[0] - T[:, :3, 3]).max() < 1e-13
    Jf = pose_jacobian(m, q, frame="base")
    bs = m.layout.base_slice
    Jf = np.concatenate([Jf[..., : bs.start], Jf[..., bs.stop:]], axis=-1)
    assert ev.J.shape[1] == ch.n_rt
    assert np.abs(ev.rows()[0] - Jf).max() < 1e-13


def test_chain_batch_equals_one_by_one():
    """A batch of parameter vectors gives the same result as evaluating each vector alone."""
    rng = np.random.default_rng(3)
    ms = [_perturbed(brtirus0707a, rng) for _ in range(4)]
    ch = Chain("dh", (2,))
    q = rng.uniform(-2, 2, (10, 6))
    parts = [ch.split_full(m.params) for m in ms]
    P = np.stack([p for p, _ in parts])
    Bs = np.stack([b for _, b in parts])
    ev = ch.evaluate(P, q, base6=Bs)
    for k in range(4):
        e1 = ch.evaluate(P[k], q, base6=Bs[k])
        assert np.array_equal(ev.J[k], e1.J[0])
        assert np.array_equal(ev.p[k], e1.p[0])


def test_chain_rejects_bad_shapes():
    """Wrong parameter or joint shapes raise ValueError naming the argument."""
    ch = Chain("mdh", (2,))
    with pytest.raises(ValueError, match="params_rt"):
        ch.evaluate(np.zeros(5), np.zeros((1, 6)))
    with pytest.raises(ValueError, match="q must"):
        ch.evaluate(np.zeros(ch.n_rt), np.zeros((1, 5)))
    with pytest.raises(ValueError, match="base6"):
        ch.evaluate(np.zeros((2, ch.n_rt)), np.zeros((1, 6)), base6=np.zeros((3, 6)))

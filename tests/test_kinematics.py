"""Tests of twin.kinematics on both papers' robots: FK, Jacobians, closed-form and iterative IK."""

import numpy as np
import pytest

from twin.kinematics import (
    RobotModel,
    UnreachableError,
    closest_branch,
    flange2base,
    inverse_kinematics_closed_form,
    inverse_kinematics_iterative,
    link_frames,
    point_jacobian,
    pose_error,
    pose_jacobian,
    tool2base,
    tool2meas,
    wrap_angle,
)
from twin.robots import brtirus0707a, get_robot, irb1200
from twin.transforms import matrix_to_rotvec

ROBOTS = [irb1200, brtirus0707a]


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _tr(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _independent_fk(model: RobotModel, q):
    """FK built here from elementary matrices, following the papers' eq. 1 literally."""
    T = model.base2meas.copy()
    for i in range(6):
        th = model.theta[i] + q[i]
        if model.convention == "mdh":
            A = _rx(model.alpha[i]) @ _tr(model.a[i], 0, 0) @ _tr(0, 0, model.d[i]) @ _rz(th) @ _ry(model.beta[i])
        else:
            A = _rz(th) @ _tr(0, 0, model.d[i]) @ _tr(model.a[i], 0, 0) @ _rx(model.alpha[i]) @ _ry(model.beta[i])
        T = T @ A
    return T @ model.tool2flange


def _random_perturbed(model, rng, scale=1e-2):
    dev = rng.normal(0, scale, model.layout.size)
    dev[model.layout.base_slice] = rng.normal(0, 0.5, 6)
    dev[model.layout.tool_slice] = rng.normal(0, 0.3, 6)
    return model.perturbed(dev)


def _random_q(model, rng, n):
    lo = np.maximum(model.q_min, -np.pi)
    hi = np.minimum(model.q_max, np.pi)
    return rng.uniform(lo, hi, (n, 6))


@pytest.mark.parametrize("make", ROBOTS)
def test_fk_matches_independent_construction(make):
    """Batched FK equals a product of elementary matrices written in the test, for perturbed models."""
    rng = np.random.default_rng(10)
    model = _random_perturbed(make(), rng)
    q = _random_q(model, rng, 50)
    T = tool2meas(model, q)
    for k in range(len(q)):
        assert np.allclose(T[k], _independent_fk(model, q[k]), atol=1e-13)


def test_irb1200_home_pose_matches_datasheet_geometry():
    """At q = 0 the IRB 1200 flange sits 351 + 82 mm forward and 399.1 + 350 + 42 mm up, facing +x."""
    T = flange2base(irb1200(), np.zeros(6))[0]
    assert np.allclose(T[:3, 3], [0.433, 0.0, 0.7911], atol=1e-12)
    assert np.allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)


def test_link_frames_end_at_the_flange():
    """link_frames returns frames 0..6 whose last entry is flange2base (and base2meas-prefixed in 'meas')."""
    rng = np.random.default_rng(11)
    model = _random_perturbed(irb1200(), rng)
    q = _random_q(model, rng, 7)
    F = link_frames(model, q)
    assert F.shape == (7, 7, 4, 4)
    assert np.allclose(F[:, 0], np.eye(4))
    assert np.allclose(F[:, 6], flange2base(model, q))
    Fm = link_frames(model, q, frame="meas")
    assert np.allclose(Fm[:, 6] @ model.tool2flange, tool2meas(model, q))


@pytest.mark.parametrize("make", ROBOTS)
@pytest.mark.parametrize("frame", ["meas", "base"])
def test_pose_jacobian_matches_central_differences(make, frame):
    """Every column of the analytic pose Jacobian equals central differences of FK (random model and q)."""
    rng = np.random.default_rng(12)
    model = _random_perturbed(make(), rng)
    q = _random_q(model, rng, 6)
    J = pose_jacobian(model, q, frame=frame)
    fk = tool2meas if frame == "meas" else tool2base
    h = 1e-6
    for k, name in enumerate(model.layout.names):
        e = np.zeros(model.layout.size)
        e[k] = h
        Tp, Tm = fk(model.with_params(model.params + e), q), fk(model.with_params(model.params - e), q)
        dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        dw = matrix_to_rotvec(Tp[:, :3, :3] @ np.swapaxes(Tm[:, :3, :3], 1, 2)) / (2 * h)
        assert np.allclose(J[:, :3, k], dp, atol=2e-8), name
        assert np.allclose(J[:, 3:, k], dw, atol=2e-8), name


@pytest.mark.parametrize("make", ROBOTS)
def test_point_jacobian_matches_central_differences(make):
    """The Jacobian of plate points (sphere centres) equals central differences of their FK positions."""
    rng = np.random.default_rng(13)
    model = _random_perturbed(make(), rng)
    q = _random_q(model, rng, 4)
    pts = rng.normal(0, 0.06, (3, 3))
    J = point_jacobian(model, q, pts)
    h = 1e-6

    def P(m):
        T = tool2meas(m, q)
        return np.einsum("nij,mj->nmi", T[:, :3, :3], pts) + T[:, None, :3, 3]

    for k in range(model.layout.size):
        e = np.zeros(model.layout.size)
        e[k] = h
        num = (P(model.with_params(model.params + e)) - P(model.with_params(model.params - e))) / (2 * h)
        assert np.allclose(J[..., k], num, atol=2e-8), model.layout.names[k]


@pytest.mark.parametrize("make", ROBOTS)
def test_closed_form_ik_reproduces_1000_poses_on_every_branch(make):
    """FK(IK(T)) == T to 1e-9 m / 1e-9 rad for 1,000 random reachable poses, every existing branch."""
    model = make()
    rng = np.random.default_rng(14)
    q = _random_q(model, rng, 1000)
    T = flange2base(model, q)
    sol = inverse_kinematics_closed_form(model, T)
    # the generating configuration is always among the branches
    dist = np.where(sol.valid, np.linalg.norm(wrap_angle(sol.q - q[:, None]), axis=-1), np.inf)
    assert dist.min(axis=1).max() < 1e-8
    Tb = flange2base(model, sol.q.reshape(-1, 6)).reshape(1000, 8, 4, 4)
    err = pose_error(np.broadcast_to(T[:, None], Tb.shape), Tb)
    ok = sol.valid
    assert np.linalg.norm(err[..., :3], axis=-1)[ok].max() < 1e-9
    assert np.linalg.norm(err[..., 3:], axis=-1)[ok].max() < 1e-9
    # every branch index is exercised somewhere
    assert ok.any(axis=0).all()


def test_irb1200_has_eight_distinct_branches_for_a_generic_pose():
    """A generic IRB 1200 pose has eight distinct solutions (2 shoulders x 2 elbows x 2 wrists)."""
    model = irb1200()
    q = np.array([[0.3, 0.2, -0.4, 0.5, 0.7, -0.2]])
    sol = inverse_kinematics_closed_form(model, flange2base(model, q))
    assert sol.valid.all()
    qs = sol.q[0]
    d = np.linalg.norm(wrap_angle(qs[:, None] - qs[None]), axis=-1)
    assert (d + np.eye(8) * 10).min() > 1e-3


@pytest.mark.parametrize("make", ROBOTS)
def test_closed_form_ik_at_wrist_singularity(make):
    """At q5 = 0 (axes 4 and 6 aligned) the solver returns a valid pose with q4 = 0 and q4+q6 preserved."""
    model = make()
    q = np.array([[0.4, 0.3, 0.2, 0.9, 0.0, -0.5]])
    T = flange2base(model, q)
    sol = inverse_kinematics_closed_form(model, T)
    assert sol.valid.any()
    Tb = flange2base(model, sol.q[0][sol.valid[0]])
    assert np.abs(pose_error(np.broadcast_to(T, Tb.shape), Tb)).max() < 1e-9
    best = closest_branch(sol, q, require_limits=False)
    assert abs(best[0, 4]) < 1e-6
    assert abs(wrap_angle(best[0, 3] + best[0, 5] - (q[0, 3] + q[0, 5]))) < 1e-6


def test_closed_form_ik_rejects_unreachable_target():
    """A target 5 m away has no branch, and closest_branch raises UnreachableError naming the target."""
    model = irb1200()
    T = np.eye(4)
    T[:3, 3] = (5.0, 0.0, 0.5)
    sol = inverse_kinematics_closed_form(model, T)
    assert not sol.valid.any()
    assert np.all(np.isfinite(sol.q))
    with pytest.raises(UnreachableError, match=r"targets \[0\]"):
        closest_branch(sol, np.zeros(6))


def test_closed_form_ik_refuses_a_model_without_parallel_axes():
    """beta2 != 0 breaks the closed form: a clear ValueError, not a wrong answer."""
    model = irb1200().perturbed({"beta2": 1e-3})
    with pytest.raises(ValueError, match="inverse_kinematics_iterative"):
        inverse_kinematics_closed_form(model, np.eye(4))


def _well_conditioned(model, q, min_sv=0.03):
    """Mask of configurations whose joint Jacobian (positions in m) is far from singular."""
    from twin.kinematics import joint_jacobian

    return np.linalg.svd(joint_jacobian(model, q), compute_uv=False)[:, -1] > min_sv


@pytest.mark.parametrize("make", ROBOTS)
def test_iterative_ik_on_perturbed_model_converges_to_1e9_mm(make):
    """Starting from the nominal closed form, Newton on a perturbed model reaches 1e-9 mm."""
    nominal = make()
    rng = np.random.default_rng(15)
    true = nominal.perturbed(rng.normal(0, 1e-3, nominal.layout.size))
    q = _random_q(nominal, rng, 400)
    q = q[_well_conditioned(nominal, q)][:200]
    assert len(q) == 200
    targets = tool2base(true, q)
    sol = inverse_kinematics_closed_form(nominal, targets @ np.linalg.inv(nominal.tool2flange))
    q0 = closest_branch(sol, q, require_limits=False)
    res = inverse_kinematics_iterative(true, targets, q0, frame="tool")
    assert res.converged.all()
    assert res.position_error.max() < 1e-12  # 1e-9 mm
    assert res.rotation_error.max() < 1e-11
    assert len(res.trace) == res.iterations
    assert np.abs(wrap_angle(res.q - q)).max() < 1e-6  # the same branch as the generating configuration


def test_iterative_ik_reports_non_convergence():
    """An unreachable target comes back with converged=False and its residual, never as a solution."""
    model = irb1200()
    T = flange2base(model, np.zeros((1, 6)))
    T[:, 0, 3] += 1.0  # 1 m beyond the reach
    res = inverse_kinematics_iterative(model, T, np.zeros((1, 6)), max_iter=20)
    assert not res.converged[0]
    assert res.position_error[0] > 0.1


def test_bad_inputs_name_the_argument():
    """Wrong shapes, NaN joints and unknown names raise ValueError naming the culprit."""
    model = irb1200()
    with pytest.raises(ValueError, match=r"q must have shape"):
        flange2base(model, np.zeros((3, 5)))
    with pytest.raises(ValueError, match="non-finite"):
        flange2base(model, np.full((1, 6), np.nan))
    with pytest.raises(ValueError, match="unknown parameter name 'd7'"):
        model.perturbed({"d7": 1.0})
    with pytest.raises(ValueError, match="unknown robot name 'ur5'"):
        get_robot("ur5")


def test_parameter_layout_has_37_named_entries_with_units():
    """Both robots carry 24 + beta2 + 6 base + 6 tool = 37 named parameters with SI units."""
    for make in ROBOTS:
        lay = make().layout
        assert lay.size == 37
        assert lay.names[24] == "beta2"
        assert lay.units[lay.index("d4")] == "m" and lay.units[lay.index("alpha4")] == "rad"
        assert lay.units[lay.index("base_rz")] == "rad" and lay.units[lay.index("tool_x")] == "m"

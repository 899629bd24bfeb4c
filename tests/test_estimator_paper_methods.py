"""The papers' identification methods: exact recovery where they can see the parameters, their solvers."""

import numpy as np
import pytest

from twin.presets import preset_deviation
from twin.robots import get_robot
from twin.transforms import pose6_to_transform
from twin.estimator import calibrate
from twin.estimator.lm import LMSettings, PoseBatch, GenericBatch, cross_identification, levenberg_marquardt
from twin.estimator.core import prepare
from twin.estimator.simulate import random_configurations, simulate_dataset
from twin.estimator.solvers import spectral_correction

from _estimator_helpers import camera_base, random_truth

CASES = [("irb1200", "spheres"), ("brtirus0707a", "pose")]


def _data(robot, kind, seed=5, base=None, n=80, given_base=False, zero=("d2",), tool_rotation=True):
    rng = np.random.default_rng(seed)
    nom = get_robot(robot)
    rot = [2e-3, -1e-3, 3e-3] if tool_rotation else [0.0, 0.0, 0.0]
    truth = random_truth(robot, rng, zero=zero).with_frames(tool2flange=pose6_to_transform([3e-4, -2e-4, 1e-4] + rot))
    B = camera_base(rng) if base is None else base
    q = random_configurations(nom, n, rng)
    ds, _ = simulate_dataset(truth, q, robot_spec=robot, kind=kind, base2meas={"0": B}, rng=rng,
                             pair=np.repeat(np.arange(n // 2), 2), set_=np.array(["calibration"] * n, dtype=object))
    if given_base:
        from dataclasses import replace
        ds = replace(ds, stations_base2meas={"0": B})
    qn = random_configurations(nom, 30, rng)
    _, tn = simulate_dataset(truth, qn, robot_spec=robot, kind=kind, base2meas={"0": B})
    _, t0 = simulate_dataset(nom, qn, robot_spec=robot, kind=kind, base2meas={"0": B})
    return truth, B, ds, qn, tn["spheres"], np.abs(tn["spheres"] - t0["spheres"]).max()


@pytest.mark.parametrize("robot,kind", CASES)
@pytest.mark.parametrize("method,options", [
    ("fullpose", {"solver": "scaled"}), ("fullpose", {"solver": "spectral"}), ("separation", {"solver": "scaled"}),
    ("lm", {}), ("clm", {}), ("lm_paper", {}), ("clm_paper", {}),
])
def test_noise_free_recovery_predicts_the_truth(robot, kind, method, options):
    """Noise-free data, errors everywhere but d2: each method's model reproduces the truth on fresh
    configurations to 1e-8 of the errors' effect (every identifiable combination is recovered)."""
    _, _, ds, qn, true_sph, effect = _data(robot, kind)
    cal = calibrate(ds, method=method, noise_position=1e-5, noise_orientation=1e-4, **options)
    assert np.abs(cal.predict(qn).spheres - true_sph).max() < 1e-8 * effect


@pytest.mark.parametrize("robot", ["irb1200", "brtirus0707a"])
def test_distance_constraint_recovers_all_but_the_base(robot):
    """Distances of the three spheres see every robot and tool combination; the base is registered after."""
    _, _, ds, qn, true_sph, effect = _data(robot, "spheres")
    for solver in ("scaled", "spectral"):
        cal = calibrate(ds, method="distance", solver=solver)
        assert np.abs(cal.predict(qn).spheres - true_sph).max() < 1e-8 * effect, solver
    assert all(s == "given" for n, s in zip(cal.names, cal.status) if n.startswith("base_"))


def test_lm_recovers_every_uncoupled_parameter_of_the_tmmdh_preset():
    """TM-MDH paper setting (Tables 3-5, identity nominal frames, 100 noise-free poses): LM over all 37
    parameters reproduces the poses; the couplings are reported and their invariant sums are right although
    their members are not (the paper's 'anomalies')."""
    nom = get_robot("brtirus0707a")
    truth = nom.perturbed(preset_deviation("tmmdh_tables_4_5"))
    rng = np.random.default_rng(0)
    q = random_configurations(nom, 100, rng)
    ds, _ = simulate_dataset(truth, q, robot_spec="brtirus0707a", kind="pose", base2meas={"0": truth.base2meas},
                             rng=rng, set_=np.array(["calibration"] * 100, dtype=object))
    from dataclasses import replace
    ds = replace(ds, stations_base2meas={"0": np.eye(4)})
    cal = calibrate(ds, method="lm", use_given_bases=True, noise_position=2e-5, noise_orientation=2e-3)
    coupled = {n for c in cal.combinations for n in c.names}
    assert {"d2", "d3", "d1", "base_z", "theta1", "base_rz", "d6", "tool_z", "a6", "tool_x", "theta6", "tool_rz",
            "alpha6", "tool_rx"} <= coupled
    xt = cal.space.from_model(truth)
    qn = random_configurations(nom, 30, rng)
    _, tn = simulate_dataset(truth, qn, robot_spec="brtirus0707a", kind="pose", base2meas={"0": truth.base2meas})
    assert np.abs(cal.predict(qn).pose[:, :3, 3] - tn["pose"][:, :3, 3]).max() < 1e-12
    # the couplings' invariants are right although their members are not: the base up to joint 1's
    # variable, the tool from joint 6's variable on, and d2 + d3 (exact for parallel axes 2-3; alpha2's tilt
    # of 3.5 mrad leaves a second-order part)
    from twin.transforms import make_transform, rot_x, rot_z

    def tz(v):
        return make_transform(np.eye(3), np.array([0, 0, v]))

    def tx(v):
        return make_transform(np.eye(3), np.array([v, 0, 0]))

    def rz(v):
        return make_transform(rot_z(v), np.zeros(3))

    def rx(v):
        return make_transform(rot_x(v), np.zeros(3))

    def inv(m):
        b = m.base2meas @ rz(m.theta[0]) @ tz(m.d[0])
        t = rz(m.theta[5]) @ tz(m.d[5]) @ tx(m.a[5]) @ rx(m.alpha[5]) @ m.tool2flange
        return b, t, m.d[1] + m.d[2]

    for a, b in zip(inv(cal.model("0")), inv(truth)):
        assert np.abs(np.asarray(a) - np.asarray(b)).max() < 1e-9


def test_separation_keeps_the_orientation_sum_of_theta2_and_theta3():
    """Step 1 identifies theta2 + theta3 from orientation changes; step 2 splits it from distances without
    changing the sum (as the paper's Tables 3 and 5: -0.4227 = -0.3047 - 0.1180). Axes 2 and 3 kept
    parallel (no beta2, alpha3 error), where the sum is exactly what orientations see."""
    truth, B, ds, *_ = _data("irb1200", "spheres", zero=("d2", "beta2", "alpha3"))
    s_true = truth.param("theta2") + truth.param("theta3")
    for solver, tol in (("spectral", 1e-9), ("scaled", 1e-12)):
        cal = calibrate(ds, method="separation", solver=solver)
        s = cal.value("theta2") + cal.value("theta3")
        assert s == cal.details["theta2_plus_theta3_step1"]
        assert s == pytest.approx(s_true, abs=tol)
    assert cal.value("theta3") == pytest.approx(truth.param("theta3"), abs=1e-10)


def test_separation_with_the_papers_euler_angle_residual():
    """With the base rotation given (dataset.toml) and the plate aligned on the flange (the paper's pins), the
    literal eq. 43 Euler-angle-change residual also recovers the robot (scaled solver) when alpha1 has no
    error. (Euler differences cannot see a plate rotation about the flange x axis, which only shifts every
    roll angle, nor theta1 at alpha1 = 0, which only shifts every yaw angle; an alpha1 error makes theta1
    weakly visible, at the level alpha1 * theta1.)"""
    _, B, ds, qn, true_sph, effect = _data("irb1200", "spheres", given_base=True, tool_rotation=False,
                                           zero=("d2", "alpha1"))
    cal = calibrate(ds, method="separation", solver="scaled", angle_residual="euler")
    assert any("dataset.toml" in n for n in cal.notes)
    assert np.abs(cal.predict(qn).spheres - true_sph).max() < 1e-8 * effect


def test_papers_methods_need_motion_pairs():
    """Distance constraints on a dataset reduced to one row per station raise a clear error."""
    _, _, ds, *_ = _data("irb1200", "spheres", n=40)
    from dataclasses import replace
    one = replace(ds.subset(np.arange(40)), pair=np.arange(40))  # every pair id used once: no pairs
    with pytest.raises(ValueError, match="no motion pairs"):
        calibrate(one, method="distance")


# --- solvers ------------------------------------------------------------------------------------------

def test_spectral_correction_equals_the_literal_iteration():
    """The closed form of eq. 36 after n steps equals iterating eq. 35 n times."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(20, 5))
    N, b, x0 = A.T @ A, rng.normal(size=5), rng.normal(size=5)
    x = x0.copy()
    M = np.linalg.inv(N + np.eye(5))
    for _ in range(7):
        x = M @ (b + x)
    r = spectral_correction(N, b, x0=x0, max_iter=7)
    assert r.iterations == 7 and np.abs(r.x - x).max() < 1e-13


def test_spectral_correction_converges_to_least_squares_and_keeps_the_null_space():
    """Well-conditioned: the least-squares solution; singular: the start value stays in the null space."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=(30, 4))
    e = rng.normal(size=30)
    r = spectral_correction(A.T @ A, A.T @ e)
    assert r.converged and np.allclose(r.x, np.linalg.lstsq(A, e, rcond=None)[0], atol=1e-10)
    A2 = np.c_[A, A[:, 0] - A[:, 1]]
    v = np.array([1.0, -1.0, 0, 0, -1.0]) / np.sqrt(3)  # null vector of A2
    x0 = 0.7 * v
    r2 = spectral_correction(A2.T @ A2, A2.T @ e, x0=x0)
    assert r2.x @ v == pytest.approx(0.7, abs=1e-9)
    assert np.allclose(A2 @ r2.x, A @ np.linalg.lstsq(A, e, rcond=None)[0], atol=1e-9)


def _tmmdh_batch(weight=1.0):
    nom = get_robot("brtirus0707a")
    truth = nom.perturbed(preset_deviation("tmmdh_tables_4_5"))
    rng = np.random.default_rng(0)
    q = random_configurations(nom, 50, rng)
    ds, _ = simulate_dataset(truth, q, robot_spec="brtirus0707a", kind="pose", base2meas={"0": truth.base2meas},
                             rng=rng, set_=np.array(["calibration"] * 50, dtype=object))
    prep = prepare(ds)
    obs = prep.obs_cal.with_sigma(weight, weight)
    return prep, PoseBatch(prep.space, obs), GenericBatch(prep.space, obs)


def test_batched_pose_problem_equals_the_generic_one():
    """The batched pose residuals and Jacobians equal the generic (per-run) ones."""
    prep, pb, gb = _tmmdh_batch()
    X = prep.x_nominal[None] + np.random.default_rng(2).normal(0, 1e-3, (3, prep.space.size))
    for part in ("full", "orientation"):
        r1, J1 = pb(X, part)
        r2, J2 = gb(X, part)
        assert np.allclose(r1, r2, atol=1e-14) and np.allclose(J1, J2, atol=1e-13)


def test_lm_batch_equals_single_runs_and_converges_from_nominal():
    """A batch of starts gives the same iterates as separate runs; from the nominal start LM fits the
    noise-free data exactly."""
    prep, pb, _ = _tmmdh_batch()
    sp = prep.space
    free = np.ones(sp.size, bool)
    X0 = np.repeat(prep.x_nominal[None], 3, axis=0)
    X0[1, sp.index("theta1")] += 0.5
    X0[2, sp.index("alpha2")] -= 0.4
    batch = levenberg_marquardt(pb, X0, free, settings=LMSettings(max_iter=30))
    for k in range(3):
        single = levenberg_marquardt(pb, X0[k:k + 1], free, settings=LMSettings(max_iter=30))
        assert np.allclose(single.X[0], batch.X[k], atol=1e-12)
    assert batch.cost[0] < 1e-24


def test_clm_orientation_stage_moves_only_angle_parameters():
    """C-LM's first stage changes angles (theta, alpha, beta, frame rotations) and leaves every length."""
    prep, pb, _ = _tmmdh_batch()
    sp = prep.space
    X0 = prep.x_nominal[None].copy()
    r = cross_identification(pb, pb, X0, np.ones(sp.size, bool), ~sp.is_length, n_cycles=1,
                             settings_full=LMSettings(max_iter=0))
    moved = np.abs(r.X[0] - X0[0]) > 0
    assert moved[~sp.is_length].any() and not moved[sp.is_length].any()


def test_separation_paper_holds_d2_and_the_tool_at_nominal():
    """The paper-literal separation variant keeps d2 and the tool at nominal (Tables 1 and 4-6 mark d2 "-";
    the plate is pinned to the flange) and uses the given base rotation."""
    _, B, ds, qn, true_sph, effect = _data("irb1200", "spheres", given_base=True, tool_rotation=False,
                                           zero=("d2", "alpha1"))
    cal = calibrate(ds, method="separation_paper", solver="scaled")
    nominal = get_robot("irb1200")
    assert cal.value("d2") == nominal.param("d2")
    assert any("paper-literal" in n for n in cal.notes) and any("dataset.toml" in n for n in cal.notes)


def test_paper_damping_refuses_a_factor_outside_the_papers_range():
    """The paper bounds lambda to [2.5, 10]; a factor outside it is a clear error naming lam."""
    with pytest.raises(ValueError, match="lam"):
        LMSettings(damping="paper", lam=100.0)
    with pytest.raises(ValueError, match="damping"):
        LMSettings(damping="sometimes")


def test_paper_damping_is_not_cumulative():
    """With the paper's rule the damping after a rise is mu0 * lam however many rises came before: on a
    problem whose cost rises at every step, the paper's LM keeps taking large steps while ours shrinks them."""

    class Rising:
        size = 1

        def __call__(self, X, part="full", jacobian=True):
            x = np.atleast_2d(X)[:, :1]
            r = np.concatenate([x, np.full_like(x, 1.0 + np.abs(x).sum())], axis=1)  # cost grows with |x|
            J = np.ones((x.shape[0], 1, 2))
            return r, J

    free = np.array([True])
    st = dict(max_iter=8, tol_step=0.0, accept="always")
    ours = levenberg_marquardt(Rising(), np.array([[1.0]]), free, settings=LMSettings(**st))
    paper = levenberg_marquardt(Rising(), np.array([[1.0]]), free, settings=LMSettings(damping="paper", **st))
    assert paper.X[0, 0] > 10 * ours.X[0, 0]

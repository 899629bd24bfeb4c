"""Change points, backlash signed by the gravity load, the base tilting under the arm's moment: each over 10 seeds.

Effects are written here with their own formulas (test-side: gravity torques and moments from the potential
energy of plausible link masses, frames changed on the true model); the diagnosis never sees them. Before/after
are the diagnosis' report rows (held out, a block of time after the rows that fit); the oracle is the estimator's
geometry re-identified on the same calibration rows with the true effect known exactly
(:func:`_diagnosis_helpers.oracle_rms`). A family is *named* on a seed when the diagnosis names it (and, for a
change, locates it within 2 rows) and its after/oracle is at most 1.2; at least 9 of 10 seeds must be (the costly
tests run one of their seeds in the suite and all 10 in the rate benchmark: :func:`_diagnosis_helpers.rate_seeds`).
"""

import functools
from dataclasses import replace

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis import diagnose
from twin.estimator.simulate import simulate_dataset
from twin.transforms import pose6_to_transform

DEG = np.pi / 180
SEEDS = 10
N_POSES = 120  # 150 rows with the repeats


def _dataset(effect=None, seed=0, t_s=True):
    m = N_POSES + N_POSES // 4
    rng = np.random.default_rng(500 + seed)
    t = np.cumsum(rng.uniform(8, 12, m)) if t_s else None
    return H.make_dataset(seed=seed, n=N_POSES, effect=effect, t_s=t)


def _change_row(seed, lo=0.2, hi=0.45):
    """The row where the change happens: in the rows that fit (the first 70 % of the campaign)."""
    m = N_POSES + N_POSES // 4
    return int(np.random.default_rng(900 + seed).integers(int(lo * m), int(hi * m)))


def _ratio(res, ds, delta):
    return res.after["position_mm"]["rms"] / H.oracle_rms(ds, delta, res.held_out["report_pose_ids"])


def _noise_free(model, q, nominal):
    from twin.dataset import default_plate

    return simulate_dataset(model, q, robot_spec="irb1200", nominal=nominal, plate=default_plate())[1]["spheres"]


def _frame_change(ds, truth, rows, *, tool=None, base=None):
    """``ds`` with the true tool (``tool``) or measurement (``base``) frame changed by the pose6 ``(6,)`` on ``rows``;
    returns the dataset and the change of the true centres ``delta`` ``(n, 3, 3)`` [m]."""
    from twin.robots import irb1200

    true = truth["true"]
    T = true.tool2flange @ pose6_to_transform(np.asarray(tool)) if tool is not None else true.tool2flange
    B = true.base2meas @ pose6_to_transform(np.asarray(base)) if base is not None else true.base2meas
    moved = true.with_frames(base2meas=B, tool2flange=T)
    q = truth["q_actual"][rows]
    delta = np.zeros_like(ds.spheres)
    delta[rows] = _noise_free(moved, q, irb1200()) - _noise_free(true, q, irb1200())
    return replace(ds, spheres=ds.spheres + delta), delta


def _one_change(res, target, row, kind="step", end=None):
    """The diagnosis reports exactly one non-minor change, of ``kind`` at ``target`` within 2 rows of ``row`` (and
    of ``end`` for a window)."""
    ch = [c for c in res.changes if not c["minor"]]
    if len(ch) != 1:
        return False
    c = ch[0]
    ok = c["kind"] == kind and c["target"] == target and c["row"] is not None and abs(c["row"] - row) <= 2
    if kind == "window":
        ok = ok and c["end_row"] is not None and abs(c["end_row"] - end) <= 2
    return ok


def _run_change(make, target, kind="step", **kw):
    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        ds, delta, row, end = make(seed, **kw)
        res = diagnose(ds)
        ratio = _ratio(res, ds, delta)
        out.append({"seed": seed, "named": _one_change(res, target, row, kind, end) and ratio <= 1.2
                    and "change" not in res.effects, "ratio": ratio})
    return out


def _joint_step(seed, t_s=True):
    s = _change_row(seed)
    b = 0.01 * DEG

    def eff(q, model):
        out = q.copy()
        out[s:, 2] += b
        return out

    ds, truth = _dataset(eff, seed=seed, t_s=t_s)
    return ds, truth["delta"], s, None


@pytest.mark.slow
def test_a_step_of_a_joint_offset_is_a_change_at_its_row():
    """Joint 3's offset steps by 0.01 deg at a row in the rows that fit: one change of theta3 within 2 rows, not
    among the effects, after <= 1.2x the oracle (>= 9/10 seeds)."""
    H.tally(_run_change(_joint_step, "theta3"), named=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_a_step_without_t_s_is_located_by_the_row_order():
    """The same step with no t_s recorded: located within 2 rows by the measurement order (>= 9/10 seeds)."""
    assert _joint_step(0, t_s=False)[0].t_s is None
    H.tally(_run_change(_joint_step, "theta3", t_s=False), named=(9, SEEDS), ratio=("median<=", 1.2))


TOOL_KNOCK = [40e-6, -30e-6, 20e-6, 2e-4, -1e-4, 1.5e-4]  # pose6 [m, rad]: the plate re-seated (40 um, 0.01 deg)
BASE_BUMP = [30e-6, 20e-6, -25e-6, -5e-5, 8e-5, 1e-4]  # pose6 [m, rad]: the instrument bumped (30 um, 0.006 deg)


def _frame_step(seed, lo=0.2, hi=0.45, **frame):
    """A clean campaign whose true tool or measurement frame (``frame``: ``tool=`` or ``base=`` pose6) changes from
    a row drawn in ``[lo, hi)`` of the rows on."""
    s = _change_row(seed, lo, hi)
    ds, truth = _dataset(None, seed=seed)
    ds, delta = _frame_change(ds, truth, np.arange(s, ds.n), **frame)
    return ds, delta, s, None


def _tool_step(seed):
    return _frame_step(seed, tool=TOOL_KNOCK)


@pytest.mark.slow
def test_a_step_of_the_tool_frame_is_a_change_at_its_row():
    """The plate re-seated on the flange (40 um, 0.01 deg) at a row in the rows that fit: one change of the tool
    frame within 2 rows, after <= 1.2x the oracle (>= 9/10 seeds)."""
    H.tally(_run_change(_tool_step, "tool"), named=(9, SEEDS), ratio=("median<=", 1.2))


def _base_step(seed):
    return _frame_step(seed, base=BASE_BUMP)


@pytest.mark.slow
def test_a_step_of_the_measurement_frame_is_a_change_at_its_row():
    """The instrument bumped (30 um, 0.006 deg) at a row in the rows that fit: one change of the base (measurement)
    frame within 2 rows, after <= 1.2x the oracle (>= 9/10 seeds)."""
    H.tally(_run_change(_base_step, "base"), named=(9, SEEDS), ratio=("median<=", 1.2))


def _payload(seed):
    s = _change_row(seed)
    c = 3e-6  # [rad / N m]: joint 2 yields to its gravity torque from the row on (a brake released, a payload)

    def eff(q, model):
        out = q.copy()
        out[s:, 1] += c * H._gravity_torque(model, q[s:])[:, 1]
        return out

    ds, truth = _dataset(eff, seed=seed)
    return ds, truth["delta"], s, None


@pytest.mark.slow
def test_a_change_of_a_joint_compliance_is_a_change_at_its_row():
    """Joint 2 starts yielding to its gravity torque at a row in the rows that fit: one change of theta2 (its
    compliance shapes) within 2 rows, after <= 1.2x the oracle (>= 9/10 seeds)."""
    out = _run_change(_payload, "theta2")
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


def _joint_window(seed):
    s = _change_row(seed, 0.1, 0.25)
    e = s + 40
    b = 0.015 * DEG

    def eff(q, model):
        out = q.copy()
        out[s:e, 1] += b
        return out

    ds, truth = _dataset(eff, seed=seed)
    return ds, truth["delta"], s, e


@pytest.mark.slow
def test_a_joint_offset_that_steps_and_back_is_a_window():
    """Joint 2's offset is off by 0.015 deg for 40 rows of the rows that fit, then back: one window change of theta2
    with both ends within 2 rows, after <= 1.2x the oracle (>= 9/10 seeds)."""
    H.tally(_run_change(_joint_window, "theta2", kind="window"), named=(9, SEEDS), ratio=("median<=", 1.2))


def test_a_glitch_of_four_rows_is_a_window_of_the_joints_zero():
    """Joint 3's zero off by 0.05 deg on 4 rows of the rows that fit (fewer than a grid window's five): one window
    change of theta3 with both ends within 2 rows, no load term among the effects."""
    s = _change_row(3)

    def eff(q, model):
        out = q.copy()
        out[s:s + 4, 2] += 0.05 * DEG
        return out

    ds, _ = _dataset(eff, seed=3)
    res = diagnose(ds)
    assert _one_change(res, "theta3", s, "window", s + 4), res.changes
    assert res.effects == (), res.effects


# ---- a change after the rows that fit ----------------------------------------------------------------------------

LATER = 20  # rows measured after the campaign (the campaign is the rest)


def _later_ratio(res, campaign, later, delta_c, delta_l):
    """RMS sphere-centre error [mm] of the diagnosis' model to use on the rows measured after the campaign, over the
    oracle's there (the estimator's geometry identified on the campaign's rows that fit, with the true effect
    removed, predicting geometry plus the true effect)."""
    from twin.diagnosis import row_context
    from twin.diagnosis.apply import predict_extended
    from twin.diagnosis.blocks import held_out_sets
    from twin.estimator import calibrate

    def rms(pred):
        e = np.linalg.norm(later.spheres - pred, axis=-1)[later.sphere_seen]
        return float(np.sqrt(np.mean(e**2)))

    cal = calibrate(H._replace(campaign, spheres=campaign.spheres - delta_c, set=held_out_sets(campaign).set))
    oracle = rms(cal.predict(later.q, later.station_ids).spheres + delta_l)
    return rms(predict_extended(res.calibration, row_context(later), later.station_ids).spheres) / oracle


def _late_case(seed, **frame):
    """A campaign whose frame changes in its held-out block (the last 30 % of its rows: from a row at 74-82 % of the
    campaign), and the rows measured after it."""
    ds, truth = _dataset(None, seed=seed)
    m = ds.n - LATER
    s = int(np.random.default_rng(900 + seed).integers(int(0.74 * m), int(0.82 * m)))
    ds, delta = _frame_change(ds, truth, np.arange(s, ds.n), **frame)
    early = np.arange(ds.n) < m
    return ds.subset(early), ds.subset(~early), delta[early], delta[~early], s


@pytest.mark.slow
@pytest.mark.parametrize("frame,target", [({"tool": TOOL_KNOCK}, "tool"), ({"base": BASE_BUMP}, "base")])
def test_a_change_in_the_held_out_block_is_kept_for_the_rows_after_the_campaign(frame, target):
    """The plate knocked (or the instrument bumped) in the campaign's held-out block, which no fit sees: one change
    of that frame within 2 rows, found after the rows that fit and confirmed after a cut, and the model to use
    predicts the rows measured after the campaign within 1.2x of the oracle (>= 9/10 seeds)."""
    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        campaign, later, delta_c, delta_l, s = _late_case(seed, **frame)
        res = diagnose(campaign)
        late = [c for c in res.changes if "found" in c]
        ratio = _later_ratio(res, campaign, later, delta_c, delta_l)
        located = len(late) == 1 and late[0]["target"] == target and abs(late[0]["row"] - s) <= 2
        out.append({"seed": seed, "named": located and res.model_in_use == "extended" and ratio <= 1.2,
                    "ratio": ratio})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
@pytest.mark.parametrize("where", [(0.2, 0.45), (0.8, 0.9)], ids=["fit-rows", "held-out-block"])
def test_a_burst_of_noisy_rows_is_not_a_change(where):
    """A clean campaign with 8 rows of 5x noise in the rows that fit, or in the held-out block: no change reported
    (>= 9/10 seeds)."""
    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        ds, _ = _dataset(None, seed=seed)
        s = _change_row(seed, *where)
        rng = np.random.default_rng(700 + seed)
        sph = ds.spheres.copy()
        sph[s:s + 8] += 4 * H.SIGMA * rng.standard_normal(sph[s:s + 8].shape)
        res = diagnose(replace(ds, spheres=sph))
        out.append({"seed": seed, "quiet": res.changes == ()})
    H.tally(out, quiet=(9, SEEDS))


@pytest.mark.slow
def test_gross_rows_are_not_a_change():
    """A clean campaign with 3 gross rows (30x the noise, one direction) in the rows that fit: no change reported
    (>= 9/10 seeds)."""
    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        ds, _ = _dataset(None, seed=seed)
        s = _change_row(seed)
        sph = ds.spheres.copy()
        sph[[s, s + 5, s + 11]] += 30 * H.SIGMA
        res = diagnose(replace(ds, spheres=sph))
        out.append({"seed": seed, "quiet": res.changes == ()})
    H.tally(out, quiet=(9, SEEDS))


# ---- the arm's own load --------------------------------------------------------------------------------------

@pytest.mark.slow
def test_backlash_signed_by_the_gravity_load_is_named_load_signed():
    """Joint 2's gear rests on the flank its gravity torque pushes it to (+-0.01 deg by the torque's sign): one
    backlash term on theta2 signed by the load (not by the last move), after <= 1.2x the oracle (>= 9/10 seeds)."""
    b = 0.01 * DEG

    def eff(q, model):
        out = q.copy()
        out[:, 1] += b * np.sign(H._gravity_torque(model, q)[:, 1])
        return out

    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        a = [x for x in res.atoms if not x["minor"]]
        ratio = _ratio(res, ds, truth["delta"])
        ok = (res.effects == ("backlash",) and len(a) == 1 and a[0]["target"] == "theta2"
              and a[0]["features"][0]["kind"] == "loadsign")
        out.append({"seed": seed, "named": ok and ratio <= 1.2, "ratio": ratio})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


def _base_moment(model, q):
    """The arm's gravity moment about the base's x and y axes ``(n, 2)`` [N m] (test-side: links' masses and centres
    of mass of :mod:`_diagnosis_helpers`)."""
    from twin.kinematics import link_frames

    F = link_frames(model, q)
    M = np.zeros((len(q), 3))
    for k, (m, c) in enumerate(zip(H.MASSES, H.COMS)):
        p = F[:, k + 1, :3, 3] + np.einsum("nij,j->ni", F[:, k + 1, :3, :3], c)
        M += np.cross(p, m * H.G)
    return M[:, :2]


@pytest.mark.slow
def test_base_tilting_under_the_arm_moment_is_named_tilt():
    """The robot's base rotates about its horizontal axes by 2e-6 rad per N m of the arm's gravity moment (masses
    unknown to the diagnosis): named tilt (the base's), or the shoulder's compliance with the base tilt as its
    alternative, after <= 1.2x the oracle (>= 9/10 seeds)."""
    from twin.robots import irb1200
    from twin.transforms import rotvec_to_matrix

    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        ds, truth = _dataset(None, seed=seed)
        true = truth["true"]
        M = _base_moment(irb1200(), truth["q_actual"])
        tilt = 2e-6 * np.column_stack([M, np.zeros(len(M))])  # [rad] about the base's x, y
        B = np.asarray(true.base2meas, float)
        R = rotvec_to_matrix(tilt)  # (n, 3, 3) in the base frame
        p_base = np.einsum("ij,nkj->nki", B[:3, :3].T, truth["spheres"] - B[:3, 3])
        moved = np.einsum("ij,nkj->nki", B[:3, :3], np.einsum("nij,nkj->nki", R, p_base)) + B[:3, 3]
        delta = moved - truth["spheres"]
        ds = replace(ds, spheres=ds.spheres + delta)
        res = diagnose(ds)
        ratio = _ratio(res, ds, delta)
        named = [a for a in res.atoms if not a["minor"]]
        tilt = "tilt" in res.effects and any(a["target"] == "tilt0" for a in named)
        # the shoulder's torque and the base's moment follow the same mass moments: where the rows cannot tell them
        # apart the shoulder's compliance is named and the tilt is its alternative
        shoulder = res.effects == ("compliance",) and any(
            d["family"] == "tilt" and d["of"] == a["label"] for a in named for d in res.alternatives)
        ok = tilt or shoulder
        out.append({"seed": seed, "named": ok and ratio <= 1.2, "effects": "+".join(res.effects), "ratio": ratio})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


# ---- the scan and the prediction -----------------------------------------------------------------------------

def test_the_scan_finds_the_row_every_step_position_scored_alone_prefers():
    """The change scan's step of joint 3 (suffix sums over all rows at once) is at the position whose atom, scored
    alone by the selection's exact scoring, explains most of every step position of joint 3."""
    from twin.diagnosis.changes import _atom, _steps, change_places, scan_changes
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis
    from twin.diagnosis.scoring import score_atoms

    ds, _, _, _ = _joint_step(3)
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    base = fit_geometry(prob, setup.x0)
    pool, sizes = atom_pool(setup)
    places = [p for p in change_places(prob.prep.nominal, [a for a in pool if a.pool == "catalogue"])
              if p.target == "theta3" and p.inner is None]
    found = scan_changes(prob, base, places, windows=False)
    assert len(found) == 1
    t = np.sort(ds.t_s[prob.rows_cal])
    every = [_atom(places[0], "t_s", 0.5 * (t[s - 1] + t[s]), None) for s in _steps(len(t))]
    scored = score_atoms(prob, base, every, sizes, exact_top=len(every))
    best = max(scored, key=lambda s: s.dchi2)
    assert best.atom.features[0].at == pytest.approx(found[0].features[0].at)


def test_a_new_session_reads_the_state_after_the_last_change():
    """A calibration with a change of joint 3's offset predicts rows without t_s (a new session) as the rows after
    the change, and rows before the change without it."""
    from twin.diagnosis.apply import effective_joints
    from twin.diagnosis.candidates import RowContext
    from twin.estimator import calibrate

    ds, _ = _dataset(None, seed=0)
    t0, t1 = float(ds.t_s[0]), float(ds.t_s[-1])
    at = 0.5 * (t0 + t1)
    cal = replace(calibrate(ds), effects=(
        {"family": "change", "place": "joint", "target": "theta3", "channel": f"change(t_s >= {at})", "label": "x",
         "features": [{"kind": "step", "ch": "t_s", "at": at, "t_span": [t0, t1]}], "values": [1e-4]},))
    q = ds.q[:4]
    before = effective_joints(cal, RowContext(q=q, t_s=np.full(4, t0)))
    after = effective_joints(cal, RowContext(q=q, t_s=np.full(4, t1)))
    new = effective_joints(cal, RowContext(q=q, t_s=None))
    assert np.allclose(before, q) and np.allclose(after[:, 2] - q[:, 2], 1e-4) and np.allclose(new, after)


def test_the_base_moment_regressor_gives_the_arm_moment_from_its_mass_moments():
    """The base's moment regressor times the links' mass moments ``(m_k, m_k c_k)`` is the arm's gravity moment about the
    base's x and y axes, summed here link by link from the centres of mass (test-side)."""
    from twin.diagnosis.candidates import base_moment_regressor
    from twin.robots import irb1200

    model = irb1200()
    q = H.configurations(np.random.default_rng(3), 20, model)
    Y = base_moment_regressor(model, q)
    w = np.concatenate([[m, *(m * np.asarray(c))] for m, c in zip(H.MASSES, H.COMS)])
    assert np.allclose(Y.reshape(len(q), 2, -1) @ w, _base_moment(model, q), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("z_min", [2.0, 3.0, 4.0])
def test_rows_to_confirm_is_the_fewest_rows_a_confirmation_can_pass_on(z_min):
    """``rows_to_confirm``: with that many rows all in favour the signed-rank score passes ``z_min`` without its most
    favourable row; with one row fewer it cannot."""
    from twin.diagnosis.late import rows_to_confirm
    from twin.diagnosis.structure import signed_rank_z

    n = rows_to_confirm(z_min)
    c = np.arange(1.0, n + 1.0)
    assert signed_rank_z(c[:-1]) > z_min
    assert signed_rank_z(c[:-2]) <= z_min


@pytest.mark.parametrize("p", [1, 3, 6])
def test_change_gains_equal_the_eigen_decomposition_of_the_projected_gram_matrix(p):
    """The scan's gains and ranks (Cholesky where nothing is dropped) are those of the eigen-decomposition of the
    unit-scaled projected Gram matrix with eigenvalues at most ``EIG_MIN`` dropped, also for nearly dependent and
    zero columns."""
    from twin.diagnosis.changes import EIG_MIN, _gains

    rng = np.random.default_rng(11 + p)
    k, m, P = 600, 40, 12
    X = rng.normal(size=(k, m, p))
    if p > 1:
        X[:200, :, 0] = X[:200, :, 1] * (1 + 1e-4 * rng.normal(size=(200, m)))  # nearly dependent columns
        X[200:300, :, -1] = 0.0  # a column without rows
    Q = np.linalg.qr(rng.normal(size=(m, P)))[0]
    A = np.einsum("mq,kmp->kqp", Q, X)
    C = np.einsum("kma,kmb->kab", X, X)
    b = 5 * rng.normal(size=(k, p))
    d = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
    D = np.where(d > 1e-12, 1 / np.where(d > 1e-12, d, 1), 0.0)
    lam, V = np.linalg.eigh((C - np.einsum("kpa,kpb->kab", A, A)) * D[:, :, None] * D[:, None, :])
    ok = lam > EIG_MIN
    proj = np.einsum("kij,ki->kj", V, b * D)
    want = np.sum(np.where(ok, proj**2 / np.where(ok, lam, 1), 0), axis=1) / 2.0
    gain, rank = _gains(C, A, b, 2.0)
    assert np.array_equal(rank, ok.sum(axis=1))
    assert np.allclose(gain, want, rtol=1e-10, atol=0)


@pytest.mark.parametrize("p", [1, 6])
def test_window_gains_from_per_index_grams_equal_those_of_each_window(p):
    """The refinement's gains from one Gram matrix per boundary and one product of the two boundary sets equal
    :func:`_gains` of every window's own ``A`` (prefix-sum differences), ranks included, in ``np.nonzero`` order."""
    from twin.diagnosis.changes import _gains, _window_gains

    rng = np.random.default_rng(3 + p)
    n, P = 300, 20
    Ai = 0.05 * rng.normal(size=(n, P, p))
    g = rng.normal(size=(n, 9, p))
    Ci = np.einsum("nka,nkb->nab", g, g)
    bi = rng.normal(size=(n, p))
    Cc, Ac, bc = (np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)]) for x in (Ci, Ai, bi))
    ia, ib = np.arange(40, 90), np.arange(60, 200)
    A2, B2 = np.meshgrid(ia, ib, indexing="ij")
    ok = (B2 - A2 >= 5) & (rng.uniform(size=A2.shape) < 0.9)
    a, b = A2[ok], B2[ok]
    gain, rank = _window_gains(Cc, Ac, bc, ia, ib, ok, 2.0)
    want, want_rank = _gains(Cc[b] - Cc[a], Ac[b] - Ac[a], bc[b] - bc[a], 2.0)
    assert np.array_equal(rank, want_rank)
    assert np.allclose(gain, want, rtol=1e-10, atol=0)


def test_the_residual_after_shared_columns_projected_off_first_is_that_of_one_least_squares():
    """The whiteness test's residual after ``[X, Y]`` (``Y``: what every change of a scan shares, projected off once,
    rank-deficient here) is the residual of one least squares on every column, to rounding."""
    from twin.diagnosis.changes import _off, _orthonormal

    rng = np.random.default_rng(7)
    m = 300
    Y = rng.normal(size=(m, 6))
    Y[:, 5] = Y[:, 0] - 2 * Y[:, 3]  # a dependent column
    X = np.hstack([rng.normal(size=(m, 3)), Y[:, :1] + 0.5 * rng.normal(size=(m, 1))])
    r = rng.normal(size=m)
    U = _orthonormal(Y)
    assert U.shape[1] == 5 and np.allclose(U.T @ U, np.eye(5), atol=1e-12)
    X1, r1 = _off(U, X), _off(U, r)
    two_stage = r1 - X1 @ np.linalg.lstsq(X1, r1, rcond=None)[0]
    A = np.hstack([X, Y])
    one = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
    assert np.allclose(two_stage, one, rtol=0, atol=1e-12 * np.linalg.norm(r))
    assert np.linalg.norm(one) > 0.5 * np.linalg.norm(r)  # most of r is left: the comparison is not of two zeros


def test_the_scan_on_two_threads_finds_what_it_finds_on_one():
    """The change scan with its places on two threads returns the same candidates, in the same order, as on one."""
    from twin.diagnosis.changes import change_places, scan_changes
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis

    ds, _, _, _ = _joint_step(3)
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    base = fit_geometry(prob, setup.x0)
    pool, _ = atom_pool(setup)
    places = change_places(prob.prep.nominal, [a for a in pool if a.pool == "catalogue"])
    assert len(places) > 4
    one = scan_changes(prob, base, places)
    prob.threads = 2
    two = scan_changes(prob, base, places)
    assert len(one) >= 1
    assert [(a.key, a.features) for a in two] == [(a.key, a.features) for a in one]


def test_a_step_ended_at_a_time_is_the_window_from_its_start_to_that_time():
    """as_window turns a kept step into a window ending at the time given (its features, channel and label), and a
    window into one with that end."""
    from twin.diagnosis.atoms import Atom
    from twin.diagnosis.changes import as_window, is_step, is_window
    from twin.diagnosis.features import Step, Window

    a = Atom("change", "joint", "theta3", (Step(ch="t_s", at=120.5),), "change(t_s >= 120.5)",
             "change of the joint 3 offset from t_s 118 on", "change", (3,))
    w = as_window(a, 300.25)
    assert is_step(a) and is_window(w) and not is_step(w)
    assert w.features == (Window(ch="t_s", at=120.5, until=300.25),) and w.pool == "change_window"
    assert w.label == "change of the joint 3 offset from t_s 120.5 until 300.25"
    assert as_window(w, 280.0).label == "change of the joint 3 offset from t_s 120.5 until 280"


# ---- a payload hung on and taken off again ------------------------------------------------------------------------


def _payload_torque(model, q, mass_kg=5.0, com_flange_m=(0.01, -0.02, 0.08)):
    """Joint torques ``(n, 6)`` [N m] of a point mass at the flange (test-side: central differences of its potential
    energy)."""
    from twin.kinematics import link_frames

    c = np.asarray(com_flange_m)

    def V(qq):
        F = link_frames(model, qq)[:, -1]
        return mass_kg * (F[:, :3, 3] + np.einsum("nij,j->ni", F[:, :3, :3], c)) @ H.G

    return H.potential_torques(V, q)


def test_a_payload_hung_on_and_off_in_the_held_out_block_is_a_window_of_the_compliance():
    """Joints 2 and 3 yield to the arm's weight on every row and to a 5 kg payload hung on in the held-out block and
    taken off 25 rows later (the rows after the campaign without it): a window of a joint's compliance within 2
    rows of both ends, found on every row, named compliance, and the rows after the campaign within 1.2x the oracle."""
    seed = 0
    ds, truth = _dataset(None, seed=seed)
    m = ds.n - LATER
    s = int(0.74 * m)
    e = s + 25
    c = np.array([0, 3e-6, 6e-6, 0, 0, 0])  # [rad / N m]

    def eff(q, model):
        on = ((np.arange(len(q)) >= s) & (np.arange(len(q)) < e)).astype(float)
        return q + c * (H._gravity_torque(model, q) + on[:, None] * _payload_torque(model, q))

    ds, truth = _dataset(eff, seed=seed)
    early = np.arange(ds.n) < m
    campaign, later = ds.subset(early), ds.subset(~early)
    res = diagnose(campaign)
    wins = [ch for ch in res.changes if ch["kind"] == "window" and ch["target"] in ("theta2", "theta3")]
    ratio = _later_ratio(res, campaign, later, truth["delta"][early], truth["delta"][~early])
    assert wins and all(abs(w["row"] - s) <= 2 and abs(w["end_row"] - e) <= 2 for w in wins), res.changes
    assert "compliance" in res.effects, res.effects
    assert ratio <= 1.2, ratio


def test_a_change_of_a_joints_gravity_torque_shapes_names_compliance():
    """A non-minor change of a joint's gravity-torque shapes (a payload) names compliance; a change of a joint's zero
    names no family (it is reported among the changes only)."""
    from twin.diagnosis.describe import name_effects

    gate = {"ch": "t_s", "at": 10.0, "t_span": [0.0, 20.0]}
    load = {"family": "change", "place": "joint", "target": "theta2", "label": "a payload", "minor": False,
            "features": [{"kind": "gated", "f": {"kind": "const"}, **gate}]}
    zero = {"family": "change", "place": "joint", "target": "theta3", "label": "a zero", "minor": False,
            "features": [{"kind": "step", **gate}]}
    assert name_effects([load])[0] == ("compliance",)
    assert name_effects([zero])[0] == ()


def test_a_payloads_torque_lies_in_the_span_of_its_shapes_at_every_joint():
    """The torque a point mass at any offset from the flange gives each joint 2-6 is a combination of that joint's
    payload shapes (the last link's mass and mass moments), on rows they were not built on."""
    from twin.diagnosis.candidates import RowContext
    from twin.diagnosis.loads import payload_shapes
    from twin.diagnosis.values import feature_values
    from twin.robots import irb1200

    model = irb1200()
    rng = np.random.default_rng(3)
    q = rng.uniform(-1.5, 1.5, (60, 6))
    tau = _payload_torque(model, q, mass_kg=4.0, com_flange_m=(0.03, -0.025, 0.12))
    for j in range(2, 7):
        F = feature_values(payload_shapes(model, rng.uniform(-1.5, 1.5, (40, 6)), j), RowContext(q=q), model)
        coef = np.linalg.lstsq(F, tau[:, j - 1], rcond=None)[0]
        assert np.linalg.norm(F @ coef - tau[:, j - 1]) <= 1e-8 * max(np.linalg.norm(tau[:, j - 1]), 1e-9), j


def test_a_payloads_change_at_one_joint_is_the_same_change_at_every_other_loaded_joint():
    """The same event of a payload's change (its start and end) is proposed at every other joint's payload place,
    never at a joint's zero, a frame or a compliance under the arm's own weight; a step's companions are steps, and a
    window taken from its start on is a step."""
    from twin.diagnosis.atoms import Atom
    from twin.diagnosis.changes import ChangePlace, as_step, same_event
    from twin.diagnosis.features import Const, Gated, Step

    places = [ChangePlace("joint", "theta2", None, "joint 2 offset", (2,)),
              ChangePlace("param", "tool", None, "tool (plate) frame")]
    places += [ChangePlace("joint", f"theta{j}", (Const(),), f"joint {j} compliance (a payload)", (j,), payload=True)
               for j in (2, 3, 5)] + [ChangePlace("joint", "theta4", (Const(),), "joint 4 compliance", (4,))]
    win = Atom("change", "joint", "theta3", (Gated(f=Const(), ch="t_s", at=10.0, until=30.0),),
               "change(10 <= t_s < 30)", "change of the joint 3 compliance (a payload) from t_s 10 until 30",
               "change_window", (3,))
    got = same_event(win, places)
    assert sorted(a.target for a in got) == ["theta2", "theta5"]
    assert all(a.features[0].at == 10.0 and a.features[0].until == 30.0 and a.pool == "change_window" for a in got)
    step = as_step(win)
    assert step.features[0].until is None and step.pool == "change" and step.label.endswith("from t_s 10 on")
    assert all(a.features[0].until is None for a in same_event(step, places))
    assert same_event(Atom("change", "joint", "theta2", (Step(ch="t_s", at=10.0),), "", "", "change", (2,)),
                      places) == []


@functools.lru_cache(maxsize=1)
def _payload_taken_off_late():
    """Joints 2 and 3 yield to the arm's weight on every row and to a 5 kg payload taken off at row ``s`` of the
    held-out block: ``(s, {target: rows where its changes leave the payload's state}, labels, later rows'
    after/oracle)`` (a step's row; a window's end: a payload carried from the first row)."""
    seed = 1
    ds, truth = _dataset(None, seed=seed)
    m = ds.n - LATER
    s = int(0.76 * m)
    c = np.array([0, 3e-6, 6e-6, 0, 0, 0])  # [rad / N m]

    def eff(q, model):
        on = (np.arange(len(q)) < s).astype(float)
        return q + c * (H._gravity_torque(model, q) + on[:, None] * _payload_torque(model, q))

    ds, truth = _dataset(eff, seed=seed)
    early = np.arange(ds.n) < m
    campaign, later = ds.subset(early), ds.subset(~early)
    res = diagnose(campaign)
    rows: dict[str, set] = {}
    for ch in res.changes:
        if ch["target"] in ("theta2", "theta3"):
            rows.setdefault(ch["target"], set()).add(ch["end_row"] if ch["kind"] == "window" else ch["row"])
    kinds = {ch["target"]: ch["label"] for ch in res.changes}
    ratio = _later_ratio(res, campaign, later, truth["delta"][early], truth["delta"][~early])
    return s, rows, kinds, ratio


def test_a_payload_taken_off_late_is_one_change_at_every_loaded_joint():
    """A payload taken off in the held-out block is one change of the compliance of joints 2 and 3 at one row, not a
    step of a joint's zero."""
    s, rows, kinds, ratio = _payload_taken_off_late()
    assert set(rows) == {"theta2", "theta3"} and rows["theta2"] & rows["theta3"], rows
    assert all("compliance" in kinds[t] for t in rows), kinds


def test_a_payload_taken_off_late_predicts_the_later_rows():
    """With a payload taken off in the held-out block read, the rows after the campaign are within 1.2x the oracle."""
    _, _, _, ratio = _payload_taken_off_late()
    assert ratio <= 1.2, ratio


@pytest.mark.xfail(strict=True, reason="the event ends at row 95, the payload came off at row 98, and joint 2 takes "
                                       "a second window to row 110 (measured)")
def test_a_payload_taken_off_late_is_located_within_two_rows():
    """The one change of a payload taken off in the held-out block starts within 2 rows of the row it came off."""
    s, rows, _, _ = _payload_taken_off_late()
    assert rows and all(abs(r - s) <= 2 for got in rows.values() for r in got), (s, rows)


def test_started_at_moves_a_steps_start_and_its_label():
    """started_at gives the same step from another row time on: every feature's start, the channel and the label."""
    from twin.diagnosis.atoms import Atom
    from twin.diagnosis.changes import started_at
    from twin.diagnosis.features import Const, Gated

    step = Atom("change", "joint", "theta3", (Gated(f=Const(), ch="t_s", at=10.0), Gated(f=Const(), ch="t_s", at=10.0)),
                "change(t_s >= 10)", "change of the joint 3 compliance (a payload) from t_s 10 on", "change", (3,))
    got = started_at(step, 12.5)
    assert all(f.at == 12.5 and f.until is None for f in got.features)
    assert got.label.endswith("from t_s 12.5 on") and got.pool == "change" and got.target == "theta3"


# ---- a change in the campaign's last rows ---------------------------------------------------------------------

END_ROWS = 8  # rows of the campaign after a change at its end (fewer than a cut needs to confirm it on later rows)


def _end_case(seed, *, joint=None, **frame):
    """A clean campaign whose joint-3 zero steps by 0.005 deg (``joint``: that joint, 0-based) or whose frame changes
    (``frame``: ``tool=``/``base=`` pose6) from its ``END_ROWS``-th last row on, kept in the rows after it."""
    ds, truth = _dataset(None, seed=seed)
    m = ds.n - LATER
    s = m - END_ROWS
    if joint is not None:
        def eff(q, model):
            out = q.copy()
            out[s:, joint] += 0.005 * DEG
            return out

        ds, truth = _dataset(eff, seed=seed)
        delta = truth["delta"]
    else:
        ds, delta = _frame_change(ds, truth, np.arange(s, ds.n), **frame)
    early = np.arange(ds.n) < m
    return ds.subset(early), ds.subset(~early), delta[early], delta[~early], s


@pytest.mark.parametrize("kw,target", [({"joint": 2}, "theta3"), ({"tool": TOOL_KNOCK}, "tool")],
                         ids=["joint-zero", "plate-knocked"])
def test_a_change_in_the_last_rows_is_kept_for_the_rows_after_the_campaign(kw, target):
    """Joint 3's zero re-latched (or the plate knocked) 8 rows before the campaign's end, too few rows after it to
    confirm it on later ones: one change there within 2 rows, judged on every row (an end change), and the model to
    use predicts the rows after the campaign within 1.5x the oracle."""
    campaign, later, delta_c, delta_l, s = _end_case(0, **kw)
    res = diagnose(campaign)
    ratio = _later_ratio(res, campaign, later, delta_c, delta_l)
    assert _one_change(res, target, s) and "judged" in res.changes[0], res.changes
    assert res.structured and res.model_in_use == "extended"
    assert ratio <= 1.5, ratio


def _end_trouble(seed, what):
    """A clean campaign (no change) with its own trouble at its end: ``burst``, its last 8 rows at 4x the noise;
    ``gross``, two of its last 3 rows a point 30x the noise off; ``wander``, the instrument's frame wandering as an
    AR(1) of the rows (rho 0.85, 0.7x the noise) on every row."""
    ds, _ = _dataset(None, seed=seed)
    m = ds.n - LATER
    rng = np.random.default_rng(700 + seed)
    sph = ds.spheres.copy()
    if what == "burst":
        sph[m - END_ROWS:m] += 4 * H.SIGMA * rng.standard_normal(sph[m - END_ROWS:m].shape)
    elif what == "gross":
        for r in (m - 1, m - 3):
            d = rng.normal(size=3)
            sph[r, rng.integers(3)] += 30 * H.SIGMA * d / np.linalg.norm(d)
    else:
        x = np.zeros((ds.n, 3))
        for i in range(1, ds.n):
            x[i] = 0.85 * x[i - 1] + np.sqrt(1 - 0.85**2) * rng.normal(size=3) * 0.7 * H.SIGMA
        sph += x[:, None, :]
    return replace(ds, spheres=sph).subset(np.arange(ds.n) < m)


@pytest.mark.parametrize("what,seed", [("burst", 0), ("gross", 0), ("wander", 9), ("wander", 11)])
def test_noisy_rows_gross_rows_or_a_wander_at_the_end_are_not_a_change(what, seed):
    """A burst of noisy rows, two gross rows or a wander of the instrument at the campaign's end is no change (the
    rows after a step fitted to the scatter of the others, significant without any one of them, against the scatter
    the rows before show along the place, AR(1) in time)."""
    res = diagnose(_end_trouble(seed, what))
    assert res.changes == (), res.changes


def test_a_step_that_ends_a_payload_hung_on_within_the_rows_is_read_as_its_window():
    """A 5 kg payload hung on at row s and taken off at row e of the rows that fit, held by a model of joint 2's
    compliance on every row and a step of its payload shapes at e: late.begun_steps reads the step as the window from
    s (within 2 rows) until e, the rows before s in the state after e."""
    from twin.diagnosis.changes import change_at, change_places, is_window
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis
    from twin.diagnosis.late import begun_steps
    from twin.diagnosis.problem import refit_with
    from twin.diagnosis.scoring import score_atoms

    s, e = 30, 80
    c = np.array([0, 6e-6, 0, 0, 0, 0])  # [rad / N m]

    def eff(q, model):
        on = ((np.arange(len(q)) >= s) & (np.arange(len(q)) < e)).astype(float)
        return q + c * (H._gravity_torque(model, q) + on[:, None] * _payload_torque(model, q))

    ds, _ = _dataset(eff, seed=2)
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    base = fit_geometry(prob, setup.x0)
    pool, _ = atom_pool(setup)
    arm = next(a for a in pool if a.pool == "catalogue" and a.family == "compliance" and a.target == "theta2")
    place = next(p for p in change_places(prob.prep.nominal, [arm], setup.ctx.q) if p.payload and p.target == "theta2")
    t = ds.t_s
    step = change_at(place, "t_s", 0.5 * (t[e - 1] + t[e]))
    sizes = {arm.pool: 1, step.pool: 1}
    chosen = [(g.atom, g.basis) for g in score_atoms(prob, base, [arm, step], sizes, exact_top=2)]
    fit = refit_with(prob, base, chosen)
    got, notes = begun_steps(setup, prob, fit, alpha=0.01)
    win = [a for a, _ in got.chosen if is_window(a)]
    assert len(win) == 1 and notes, [a.label for a, _ in got.chosen]
    f0 = win[0].features[0]
    assert abs(int(np.searchsorted(t, f0.at)) - s) <= 2 and f0.until == step.features[0].at, win[0].label


def test_the_selection_scans_short_windows_only_where_the_grid_is_fine():
    """The selection's short windows (from MIN_ROWS rows at every row) are scanned on a campaign of a few hundred
    calibration rows and left to the glitch scan on one of thousands (their count grows faster than the rows)."""
    from twin.diagnosis.changes import MIN_ROWS, WINDOW_MIN_ROWS, _short_pairs, selection_short

    assert selection_short(200) == MIN_ROWS
    assert selection_short(12000) is None
    small = _short_pairs(200, MIN_ROWS)
    assert int(np.max(small[1] - small[0])) <= 2 * WINDOW_MIN_ROWS - 1
    assert len(_short_pairs(12000, MIN_ROWS)[0]) > 100 * len(small[0])


@pytest.mark.parametrize("n", [200, 533, 534, 1000, 3000])
def test_a_short_window_is_tried_from_every_row_up_to_533_rows_and_every_few_beyond(n, monkeypatch):
    """Every short window (from MIN_ROWS rows to two grid strides) is tried on a scan of up to 533 rows; beyond, a
    window of w rows is tried from every max(1, w // 8)-th row, so each one not tried has a tried one of its width
    starting fewer than w // 8 rows before it."""
    from twin.diagnosis import changes as C

    share = C.SHORT_START_SHARE
    sub = set(zip(*(x.tolist() for x in C._short_pairs(n, C.MIN_ROWS))))
    monkeypatch.setattr(C, "SHORT_START_SHARE", 10**9)
    every = set(zip(*(x.tolist() for x in C._short_pairs(n, C.MIN_ROWS))))
    assert sub <= every
    if n <= 533:
        assert sub == every
        return
    assert len(sub) < len(every)
    for a, b in every - sub:
        w = b - a
        assert any((a - k, b - k) in sub for k in range(1, max(1, w // share))), (a, b)


@pytest.mark.parametrize("seed", range(4))
def test_a_glitch_off_the_short_windows_start_rows_is_found_at_its_rows(seed, monkeypatch):
    """A joint's zero off on 16 to two grid strides of rows of 750 calibration rows (joint, width, start and size
    drawn per seed), from a row no window of that width is tried from: the scan's window takes exactly the glitch's
    rows, as the scan trying every row does."""
    from twin.diagnosis import changes as C
    from twin.diagnosis.changes import MIN_ROWS, WINDOW_GRID, _steps, change_places, is_window, scan_changes
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis

    rng = np.random.default_rng(4000 + seed)
    n_poses, n_cal = 1000, 750
    steps = _steps(n_cal)
    stride = int(np.ceil(len(steps) / WINDOW_GRID))
    joint = int(rng.integers(1, 7))
    w = int(rng.integers(2 * C.SHORT_START_SHARE, 2 * stride))
    lo = int(rng.integers(100, 600))
    while (lo - steps[0]) % max(1, w // C.SHORT_START_SHARE) == 0:
        lo += 1
    hi = lo + w
    size_deg = rng.uniform(0.03, 0.08) * (3 if joint >= 4 else 1)  # a wrist joint's zero moves the plate less

    def eff(q, model):
        out = q.copy()
        out[lo:hi, joint - 1] += size_deg * DEG
        return out

    t = np.cumsum(rng.uniform(8, 12, n_poses + n_poses // 4))
    ds, _ = H.make_dataset(seed=seed, n=n_poses, effect=eff, t_s=t)
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    assert prob.obs_cal.n == n_cal and np.array_equal(prob.rows_cal[:hi + 1], np.arange(hi + 1))
    a, b = C._short_pairs(n_cal, MIN_ROWS)
    assert not np.any((a == lo) & (b == hi))  # the glitch's own window is not among those tried
    base = fit_geometry(prob, setup.x0)
    pool, _ = atom_pool(setup)
    places = [p for p in change_places(prob.prep.nominal, [x for x in pool if x.pool == "catalogue"])
              if p.target == f"theta{joint}" and p.inner is None]
    t_cal = np.sort(ds.t_s[prob.rows_cal])

    def window_rows(found):
        win = [x for x in found if is_window(x)]
        assert len(win) == 1, [x.label for x in found]
        f0 = win[0].features[0]
        return int(np.searchsorted(t_cal, f0.at)), int(np.searchsorted(t_cal, f0.until))

    sub = window_rows(scan_changes(prob, base, places, windows=True, short=MIN_ROWS))
    monkeypatch.setattr(C, "SHORT_START_SHARE", 10**9)  # every short window from every row
    every = window_rows(scan_changes.__wrapped__(prob, base, places, windows=True, short=MIN_ROWS))
    assert sub == every == (lo, hi), (joint, w, lo, size_deg)


def test_rows_left_out_for_their_history_are_no_run_of_gross_rows():
    """gross_runs (the glitch scan's runs of gross rows, read again) counts the calibration rows at weight 0 as
    gross, and not those a kept term lacks the history of (update_gross leaves them out of every fit)."""
    from twin.diagnosis.diagnose import prepare_diagnosis
    from twin.diagnosis.late import gross_runs

    ds, _, _, _ = _joint_step(0)
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    first = np.argsort(ds.t_s[prob.rows_cal], kind="stable")[:4]
    prob.w_cal = np.ones(prob.obs_cal.n)
    prob.w_cal[first] = 0.0
    assert gross_runs(setup, prob)[first].tolist() == [1.0] * 4
    prob.history_out = np.zeros(prob.obs_cal.n, bool)
    prob.history_out[first] = True
    assert not gross_runs(setup, prob).any()


@pytest.mark.parametrize("seed", range(3))
def test_rows_outside_a_window_that_hold_a_change_are_structured_and_white_rows_are_not(seed):
    """window_wander: a window of a joint's zero begun at a wrong row (the zero was off from the first row to the
    window's end; joint, size and rows drawn) leaves rows outside it that hold the change (their mean square evidence
    beyond STRUCTURED_OUTSIDE), so it is turned down as no wander; the same window on a campaign without the change
    has rows outside it at the floor."""
    from twin.diagnosis.changes import STRUCTURED_OUTSIDE, as_window, change_at, change_places, row_times, window_wander
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis
    from twin.diagnosis.scoring import score_atoms

    rng = np.random.default_rng(70 + seed)
    m = N_POSES + N_POSES // 4
    joint = int(rng.integers(1, 7))
    end = int(rng.integers(int(0.35 * m), int(0.55 * m)))
    start = int(rng.integers(end // 3, 2 * end // 3))
    size_deg = rng.uniform(0.02, 0.05) * (3 if joint >= 4 else 1)

    def eff(q, model):
        out = q.copy()
        out[:end, joint - 1] += size_deg * DEG
        return out

    got = []
    for effect in (eff, None):
        ds, _ = _dataset(effect, seed=seed)
        setup = prepare_diagnosis(ds)
        prob = setup.problem
        fit = fit_geometry(prob, setup.x0)
        _, sizes = atom_pool(setup)
        pl = next(p for p in change_places(prob.prep.nominal, []) if p.target == f"theta{joint}" and p.inner is None)
        ch, t = row_times(prob.ctx)
        win = as_window(change_at(pl, ch, 0.5 * (t[start - 1] + t[start])), 0.5 * (t[end - 1] + t[end]))
        got.append(window_wander(prob, fit, score_atoms(prob, fit, [win], sizes)[0], sizes)[1])
    s2, s2_clean = got
    assert s2 > STRUCTURED_OUTSIDE, (joint, start, end, size_deg, s2)
    assert s2_clean < 3.0, s2_clean

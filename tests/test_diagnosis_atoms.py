"""The diagnosis' atoms, one behaviour per test, each over 10 seeds with a stated pass rate.

Effects are written here with their own formulas (not the diagnosis' regressors); every dataset records ``t_s``
and ``temp_c`` whatever the effect, so no channel hints at the answer. Before/after are the diagnosis' report
rows (held out, used for nothing else); the oracle is the estimator's geometry re-identified on the same
calibration rows with the true effect known exactly (:func:`_diagnosis_helpers.oracle_rms`: estimator code only).
A selection outcome must hold on at least 9 of 10 seeds and the median after/oracle stay within the bound (the
costly tests run one seed in the suite and all 10 in the rate benchmark: :func:`_diagnosis_helpers.rate_seeds`).
"""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis import diagnose

DEG = np.pi / 180
SEEDS = 10


def _own_approach(q, start):
    """Sign of each joint's last move, from a given start (test-side code)."""
    out = np.empty_like(q)
    last = np.sign(q[0] - start)
    last[last == 0] = 1.0
    prev = q[0]
    out[0] = last
    for k in range(1, len(q)):
        d = np.sign(q[k] - prev)
        last = np.where(d != 0, d, last)
        out[k] = last
        prev = q[k]
    return out


def _dataset(effect, seed=0, n=160):
    m = n + n // 4  # rows incl. repeats (make_dataset repeats every 4th pose)
    rng = np.random.default_rng(100 + seed)
    t = np.cumsum(rng.uniform(8, 12, m))
    temp = 21.0 + 0.3 * rng.standard_normal(m)
    return H.make_dataset(seed=seed, n=n, effect=effect, t_s=t, temp=temp)


def _ratio(res, ds, truth):
    """after / oracle on the diagnosis' report rows."""
    return res.after["position_mm"]["rms"] / H.oracle_rms(ds, truth["delta"], res.held_out["report_pose_ids"])


def _named(res):
    return [a for a in res.atoms if not a["minor"]]


@pytest.mark.slow
def test_partial_explanation_is_kept():
    """A backlash plus an effect nothing can express: the backlash is named and stays in the model, after < 0.6x
    before on the report rows and a partial explained fraction (>= 9/10 seeds)."""
    def eff(q, model):
        out = q + 0.01 * DEG * _own_approach(q, np.zeros(6)) * np.array([0, 1, 0, 0, 0, 0])
        out[:, 1] += 0.004 * DEG * np.sin(7 * q[:, 2] + 3 * q[:, 3])
        return out

    out = []
    for seed in H.rate_seeds(range(1, 1 + SEEDS)):
        ds, _ = _dataset(eff, seed=seed)
        res = diagnose(ds)
        out.append({"seed": seed, "named": res.structured and "backlash" in res.effects,
                    "better": res.after["position_mm"]["rms"] < 0.6 * res.before["position_mm"]["rms"],
                    "partial": 0.3 < res.explained_fraction < 1.0})
    H.tally(out, named=(9, SEEDS), better=(9, SEEDS), partial=(9, SEEDS))


@pytest.mark.slow
def test_unknown_first_approach_does_not_veto_backlash():
    """The robot came from far away before the first row: that row is flagged, backlash is named and explained,
    and the clearance recovered within 5 % on joints 2 and 3 (>= 9/10 seeds)."""
    start = np.array([1.0, -0.5, 0.5, -1.5, 1.2, 2.0])
    b = 0.008 * DEG
    out = []
    for seed in H.rate_seeds(range(20, 20 + SEEDS)):
        ds, _ = _dataset(lambda q, m: q + b * _own_approach(q, start) * np.array([0, 1, 1, 0, 0, 0]), seed=seed)
        res = diagnose(ds)
        vals = {a["target"]: abs(a["values"][0]) for a in res.atoms}
        out.append({"seed": seed, "named": res.effects == ("backlash",) and res.explained,
                    "flagged": 0 in res.rows["unknown_history"],
                    "clearance": all(abs(vals.get(t, 0.0) / b - 1) < 0.05 for t in ("theta2", "theta3"))})
    H.tally(out, named=(9, SEEDS), flagged=(SEEDS, SEEDS), clearance=(9, SEEDS))


@pytest.mark.parametrize("seed", range(6))
def test_rows_before_a_backlash_joint_first_moves_are_left_out_and_read_as_no_change(seed):
    """A short campaign (36-48 poses, its first pose measured twice) on a robot with a backlash of a drawn joint, size
    and start: the rows before that joint first moves are left out of the fit (they carry the whole backlash
    unexplained), backlash is named and no change of a frame or a joint is read from them."""
    rng = np.random.default_rng(4400 + seed)
    mask = np.zeros(6)
    mask[int(rng.integers(1, 6))] = 1.0
    b = rng.uniform(0.02, 0.06) * DEG
    start = rng.uniform(-2.0, 2.0, 6)
    ds, _ = _dataset(lambda q, m: q + b * _own_approach(q, start) * mask, seed=seed, n=4 * int(rng.integers(9, 13)))
    res = diagnose(ds)
    assert {0, 1} <= set(res.rows["left_out_history"]), res.rows
    assert "backlash" in res.effects and not [c["label"] for c in res.changes if not c["minor"]], \
        (res.effects, [c["label"] for c in res.changes])


@pytest.mark.slow
def test_single_harmonic_on_one_joint_is_one_atom_near_the_oracle():
    """One harmonic on one joint: the one non-minor term is that joint and order with its amplitude within 10 %
    (>= 9/10 seeds), at a median after/oracle <= 1.2."""
    amp = 0.01 * DEG

    def eff(q, model):
        out = q.copy()
        out[:, 3] += amp * np.sin(2 * q[:, 3] + 0.7)
        return out

    out = []
    for seed in H.rate_seeds(range(30, 30 + SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        named = _named(res)
        one = len(named) == 1 and named[0]["label"] == "joint 4, 2nd harmonic"
        out.append({"seed": seed, "named": one and named[0]["size"]["amplitude"] == pytest.approx(0.01, rel=0.1),
                    "ratio": _ratio(res, ds, truth)})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_coupling_outside_the_catalogue_is_traced_to_channel_and_place():
    """theta3 += c q2 (no catalogue term): structured, no catalogue name, an unnamed term with channel q2 on
    joint 3 (>= 9/10 seeds), median after/oracle <= 1.2."""
    def eff(q, model):
        out = q.copy()
        out[:, 2] += 4e-4 * q[:, 1]
        return out

    out = []
    for seed in H.rate_seeds(range(40, 40 + SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        out.append({"seed": seed, "traced": res.structured and res.effects == () and any(
            a["channel"] == "q2" and a["target"] == "theta3" for a in res.unnamed), "ratio": _ratio(res, ds, truth)})
    H.tally(out, traced=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_quadratic_in_one_joint_is_not_named_as_a_catalogue_effect():
    """theta3 += c (q3 - q0)^2 is reported unnamed on joint 3 with channel q3^2, or with a catalogue name only
    alongside that reading as the alternative (>= 9/10 seeds), median after/oracle <= 1.2."""
    def eff(q, model):
        out = q.copy()
        out[:, 2] += 0.01 * DEG * ((q[:, 2] + 0.2) / 0.8) ** 2
        return out

    out = []
    for seed in H.rate_seeds(range(50, 50 + SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        traced = any(a["channel"] == "q3^2" and a["target"] == "theta3" for a in res.unnamed)
        alt = any(d["channel"] == "q3^2" and d["target"] == "theta3" for d in res.alternatives)
        out.append({"seed": seed, "traced": res.structured and (traced or alt), "ratio": _ratio(res, ds, truth)})
    H.tally(out, traced=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_clean_data_with_every_channel_recorded_raise_no_alarm():
    """No effect, t_s and temp_c recorded: no alarm in at least 9 of 10 seeds, and without one the extended
    model is the geometric."""
    alarms = 0
    for seed in range(10):
        ds, _ = _dataset(None, seed=10 + seed, n=120)
        res = diagnose(ds)
        alarms += res.structured
        if not res.structured:
            assert res.atoms == () and res.after == res.before
    assert alarms <= 1


@pytest.mark.slow
def test_one_gross_row_is_down_weighted_not_decisive():
    """A single held-out row 30x off (in the confirmation block, at 80 % of the campaign) is listed as gross and does
    not make clean data structured (>= 9/10 seeds)."""
    from dataclasses import replace

    out = []
    for seed in range(60, 60 + SEEDS):
        ds, _ = _dataset(None, seed=seed, n=120)
        k = int(0.8 * ds.n)
        sph = ds.spheres.copy()
        sph[k] += 30 * H.SIGMA
        res = diagnose(replace(ds, spheres=sph))
        gross = res.rows["gross_validation"] + res.held_out["gross_report_pose_ids"]
        out.append({"seed": seed, "listed": int(ds.pose_id[k]) in gross, "quiet": not res.structured})
    H.tally(out, listed=(SEEDS, SEEDS), quiet=(9, SEEDS))


# ---- found on blind campaigns written by another generator (studies/blind) -------------------------------------

def _lagged_own(temp, t, tau, substeps=50):
    """First-order lag of ``temp`` over the times ``t`` by explicit Euler substeps (test-side code)."""
    y = np.empty_like(temp)
    y[0] = temp[0]
    for k in range(1, len(t)):
        h = (t[k] - t[k - 1]) / substeps
        v = y[k - 1]
        for _ in range(substeps):
            v += h * (temp[k] - v) / tau
        y[k] = v
    return y


@pytest.mark.slow
def test_wrist_coupling_of_joint5_with_joint4_is_named():
    """theta5 += c q4 (joint 5's drive passes through joint 4): named coupling, one non-minor term on joint 5
    with channel q4 and c within 5 % (>= 9/10 seeds), median after/oracle <= 1.2."""
    def eff(q, model):
        out = q.copy()
        out[:, 4] += 5e-4 * q[:, 3]
        return out

    out = []
    for seed in H.rate_seeds(range(70, 70 + SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        a = _named(res)
        ok = res.effects == ("coupling",) and len(a) == 1 and a[0]["target"] == "theta5" and a[0]["channel"] == "q4"
        out.append({"seed": seed, "named": ok and a[0]["values"][0] == pytest.approx(5e-4, rel=0.05),
                    "ratio": _ratio(res, ds, truth)})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_growth_with_a_lagged_temperature_is_thermal_with_its_time_constant():
    """All lengths grow with the links' temperature, which lags the recorded air temperature by tau = 1500 s:
    named thermal on the lagged temperature with tau within 30 %, the remainder not structured (>= 9/10 seeds). The
    campaign lasts about three time constants, so that its first half (the rows that fit; the held-out rows are the
    end of the campaign) sees the lag."""
    out = []
    for seed in H.rate_seeds(range(80, 80 + SEEDS), suite=(82, 89)):  # read as the motors' heat with a warm-up once
        n = 320
        m = n + n // 4
        rng = np.random.default_rng(seed)
        t = np.cumsum(rng.uniform(10, 15, m))
        air = 20.0 + 4.0 * (1 - np.exp(-t / 1200.0)) + 0.05 * rng.standard_normal(m)
        link = _lagged_own(air, t, 1500.0)
        ds, _ = H.make_dataset(seed=seed, n=n, effect=("lengths", 40e-6 * (link - 20.0)), t_s=t, temp=air)
        res = diagnose(ds)
        a = _named(res)
        f = a[0]["features"][0] if a else {}
        out.append({"seed": seed, "named": res.effects == ("thermal",) and res.explained and f.get("kind") == "lag"
                    and f["tau"] == pytest.approx(1500.0, rel=0.3)})
    H.tally(out, named=(9, SEEDS))


@pytest.mark.slow
def test_the_air_s_step_in_the_last_rows_is_read_with_the_recorded_temperature():
    """The recorded air steps up 6 K before the campaign's last 6 rows (too few to locate a change on some rows and
    confirm it on others), the links following it with a lag of 200 s: named thermal against the recorded temperature
    through a lag, found on every row (no selection runs: the blocks before those rows are at the floor)."""
    n = 200
    m = n + n // 4
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(10, 15, m))
    t[-6:] += 600.0  # a pause before the last rows
    air = 20.0 + 0.05 * rng.standard_normal(m)
    air[-6:] += 6.0
    link = _lagged_own(air, t, 200.0)
    ds, _ = H.make_dataset(seed=7, n=n, effect=("lengths", 40e-6 * (link - 20.0)), t_s=t, temp=air)
    res = diagnose(ds)
    a = _named(res)
    assert res.effects == ("thermal",) and len(a) == 1 and a[0]["features"][0]["kind"] == "lag"
    assert any(n.startswith("the recorded temperature leaving its range in the campaign's last rows") for n in res.notes)


@pytest.mark.slow
def test_warm_up_drift_of_the_measurement_frame_extrapolates():
    """The instrument's frame drifts as it warms up (a settling translation, no temperature recorded): a
    transient term is found, and predicting the next 25 rows (after the data) stays within 1.3x of the noise
    (>= 9/10 seeds)."""
    from dataclasses import replace

    from twin.diagnosis.apply import predict_extended
    from twin.diagnosis.candidates import RowContext

    out = []
    for seed in H.rate_seeds(range(90, 90 + SEEDS)):
        n = 220
        m = n + n // 4
        t = np.arange(m) * 12.0
        ds, _ = H.make_dataset(seed=seed, n=n, t_s=t)
        drift = 0.03e-3 * (1 - np.exp(-(t + 300.0) / 1000.0))
        sph = ds.spheres.copy()
        sph[:, :, 0] += drift[:, None]
        sph[:, :, 2] -= 0.5 * drift[:, None]
        full = replace(ds, spheres=sph)
        k = m - 25
        res = diagnose(full.subset(np.arange(k)))
        ctx = RowContext(q=full.q, t_s=full.t_s, station=None)
        pred = predict_extended(res.calibration, ctx).spheres
        err = np.linalg.norm(pred[k:] - full.spheres[k:], axis=-1)
        out.append({"seed": seed, "found": res.structured and any("exp" in a["channel"] for a in _named(res)),
                    "later": float(np.sqrt(np.mean(err**2))) < 1.3 * np.sqrt(3) * H.SIGMA})
    H.tally(out, found=(9, SEEDS), later=(9, SEEDS))


@pytest.mark.slow
def test_one_sided_pull_is_traced_to_q5_and_not_named():
    """A cable pulling joint 5 back past +45 deg, growing with the square of the overtravel (no catalogue term):
    structured, traced to joint 5 and q5 only, no catalogue name (>= 9/10 seeds), median after/oracle <= 1.5."""
    def eff(q, model):
        out = q.copy()
        out[:, 4] -= 0.03 * DEG * (np.clip(q[:, 4] - 45 * DEG, 0, None) / (30 * DEG)) ** 2
        return out

    out = []
    for seed in H.rate_seeds(range(100, 100 + SEEDS)):
        ds, truth = _dataset(eff, seed=seed)
        res = diagnose(ds)
        on5 = [a for a in _named(res) if a["target"] == "theta5"]
        out.append({"seed": seed, "traced": res.structured and bool(on5) and all("q5" in a["channel"] for a in on5),
                    "unnamed": res.effects == (), "ratio": _ratio(res, ds, truth)})
    H.tally(out, traced=(9, SEEDS), unnamed=(9, SEEDS), ratio=("median<=", 1.5))


@pytest.mark.slow
def test_stand_swaying_with_a_cycle_in_time_is_found_with_its_period():
    """The instrument's stand sways with the air conditioning (a translation and a tilt of the measurement
    frame, sinusoidal in time with a 17-minute period): one non-minor term, on the measurement frame in t_s with
    its period within 2 % (>= 9/10 seeds), median after/oracle <= 1.2."""
    from dataclasses import replace

    from twin.transforms import pose6_to_transform

    P = 1020.0
    out = []
    for seed in H.rate_seeds(range(110, 110 + SEEDS)):
        ds, _ = _dataset(None, seed=seed, n=200)
        s = np.sin(2 * np.pi * ds.t_s / P + 0.8)
        sph = ds.spheres.copy()
        for k in range(ds.n):
            T = pose6_to_transform(s[k] * np.array([15e-6, -10e-6, 5e-6, 2e-5, -3e-5, 1e-5]))
            sph[k] = sph[k] @ T[:3, :3].T + T[:3, 3]
        delta = sph - ds.spheres
        ds = replace(ds, spheres=sph)
        res = diagnose(ds)
        a = _named(res)
        ok = len(a) == 1 and a[0]["target"] == "base" and a[0]["features"][0]["ch"] == "t_s"
        out.append({"seed": seed, "found": ok and 2 * np.pi / a[0]["features"][0]["k"] == pytest.approx(P, rel=0.02),
                    "ratio": res.after["position_mm"]["rms"] / H.oracle_rms(ds, delta, res.held_out["report_pose_ids"])})
    H.tally(out, found=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_a_joint1_backlash_is_named_though_the_base_frame_holds_it_too():
    """Joint 1 backlash is a rotation about base z, which the base frame's six directions hold as well: the
    named term on joint 1 is the one non-minor term, not the unnamed frame term that contains it (>= 9/10
    seeds)."""
    b = 0.006 * DEG
    out = []
    for seed in H.rate_seeds(range(120, 120 + SEEDS)):
        ds, _ = _dataset(lambda q, m: q + b * _own_approach(q, np.zeros(6)) * np.array([1, 0, 0, 0, 0, 0]), seed=seed)
        res = diagnose(ds)
        out.append({"seed": seed, "named": res.effects == ("backlash",)
                    and [a["target"] for a in _named(res)] == ["theta1"]})
    H.tally(out, named=(9, SEEDS))


def _own_play(u, h):
    """A play of half clearance ``h`` on the command ``u``, the joint coming from below (test-side code)."""
    o = u[0] - h
    out = np.empty_like(u)
    for k in range(len(u)):
        o = min(max(o, u[k] - h), u[k] + h)
        out[k] = o - u[k]
    return out


@pytest.mark.slow
def test_backlash_with_short_moves_becomes_a_play_with_its_clearance(monkeypatch):
    """Joint 2 has a clearance of +-0.3 deg and every third move of it is shorter than the clearance (it does
    not switch the side): the one backlash term is a play operator with the clearance within 1 % and after
    <= 1.2x the oracle (>= 9/10 seeds), median after/oracle <= 1.2."""
    def eff(q, model):
        out = q.copy()
        out[:, 1] += _own_play(q[:, 1], 0.3 * DEG)
        return out

    orig = H.configurations
    out = []
    for seed in H.rate_seeds(range(17, 17 + SEEDS)):
        rng = np.random.default_rng(seed)

        def with_short_moves(r, n, model):
            q = orig(rng, n, model)
            for k in range(1, n, 3):
                q[k] = q[k - 1]
                q[k, 1] += rng.choice([-1, 1]) * rng.uniform(0.1, 0.5) * DEG
            return q

        monkeypatch.setattr(H, "configurations", with_short_moves)
        ds, truth = _dataset(eff, seed=seed, n=200)
        monkeypatch.setattr(H, "configurations", orig)
        res = diagnose(ds)
        a = _named(res)
        f = a[0]["features"][0] if len(a) == 1 else {}
        ratio = _ratio(res, ds, truth)
        out.append({"seed": seed, "play": res.effects == ("backlash",) and f.get("kind") == "play"
                    and f["h"] == pytest.approx(0.3 * DEG, rel=0.01) and ratio <= 1.2, "ratio": ratio})
    H.tally(out, play=(9, SEEDS), ratio=("median<=", 1.2))


def test_every_feature_reads_the_same_on_rows_that_continue():
    """Every atom's features on a campaign's rows equal those on the same rows followed by later ones (what
    `twin predict` sees when it predicts the rows after a campaign): no feature is scaled or centred on the rows
    it is given."""
    from dataclasses import replace

    from twin.diagnosis.pools import catalogue_atoms, generic_atoms
    from twin.diagnosis.values import feature_values
    from twin.diagnosis.floor import row_context

    ds, _ = _dataset(None, seed=18, n=120)
    ds = replace(ds, station=np.where(np.arange(ds.n) < ds.n // 2, "left", "right").astype(object),
                 status=np.where(np.arange(ds.n) == 70, "restart", "").astype(object))
    full = row_context(ds)
    k = ds.n - 30
    part = row_context(ds.subset(np.arange(k)))
    lengths = ["a3", "d4"]
    params = ["a3", "d4", "alpha2"]
    cat = catalogue_atoms(ds.robot, part, lengths)
    pool = cat + generic_atoms(ds.robot, part, params, lengths, cat, points=ds.spheres[:k],
                               plate_spheres=ds.plate.spheres_flange)
    kinds = set()
    for a in pool[::7] + [a for a in pool if {f.kind for f in a.features} & {"heat", "lag", "play", "settle",
                                                                                   "stepin", "cartdir", "gated"}]:
        if a.place == "field":
            continue  # functions of the measured point, not of the rows
        kinds |= {f.kind for f in a.features}
        assert np.allclose(feature_values(a.features, full, ds.robot)[:k], feature_values(a.features, part, ds.robot),
                           rtol=1e-9, atol=1e-12), a.label
    assert {"heat", "lag", "exp", "settle", "stepin", "cartdir", "gated", "step", "sign", "lastmove"} <= kinds


def test_the_catalogue_reads_the_heat_of_each_moving_motor_on_each_link():
    """The thermal catalogue of a campaign with t_s offers, per link and for all links, the heat of each motor group
    alone, of the groups with a warm-up, and of every joint that moves alone, a joint that travels little beside a
    wide-ranging wrist joint included; a joint that never moves has no heat of its own."""
    from twin.diagnosis.candidates import RowContext
    from twin.diagnosis.features import Heat
    from twin.diagnosis.pools import catalogue_atoms, heat_alternatives
    from twin.robots import irb1200

    rng = np.random.default_rng(3)
    n = 60
    q = rng.uniform(-0.5, 0.5, size=(n, 6))
    q[:, 0] = 0.01 * rng.uniform(size=n)  # joint 1 travels little
    q[:, 5] = rng.uniform(-3.0, 3.0, size=n)  # joint 6 sweeps a wide range
    q[:, 3] = 0.2  # joint 4 never moves
    ctx = RowContext(q=q, t_s=np.cumsum(rng.uniform(10.0, 30.0, size=n)))
    cat = catalogue_atoms(irb1200(), ctx, ["a3", "d4"])
    heat = {(a.target, tuple(f.joints for f in a.features if isinstance(f, Heat))) for a in cat
            if a.family == "thermal" and any(isinstance(f, Heat) for f in a.features)}
    for target in ("all_lengths", "a3", "d4"):
        assert {(target, ((j,),)) for j in (1, 2, 3, 5, 6)} <= heat
        assert (target, ((4,),)) not in heat
        assert {(target, ((1, 2, 3),)), (target, ((4, 5, 6),)), (target, ((1, 2, 3), (4, 5, 6)))} <= heat
    one = next(a for a in cat if a.target == "a3" and a.channel.startswith("joint 1's motion heat"))
    alts = heat_alternatives(ctx, one)
    assert all(a.target == "a3" and a.family == "thermal" for a in alts)
    assert {tuple(f.joints for f in a.features if isinstance(f, Heat)) for a in alts} >= {((1, 2, 3),), ((6,),)}
    assert ((1,),) not in {tuple(f.joints for f in a.features if isinstance(f, Heat)) for a in alts}

"""Tests of twin.diagnosis on synthetic sphere-centre data with the instrument's noise (no rendering).

Effects are injected undeclared (nothing about them reaches the dataset but the commanded joints, the row
order and, for thermal growth, the recorded temperature). Sizes are >= 3x the noise after a perfect
geometric-only calibration (``effect_size``). A selection outcome is tested over 10 seeds with a stated pass
rate (the costly ones on one of their seeds in the suite and on all 10 in the rate benchmark:
:func:`_diagnosis_helpers.rate_seeds`); before/after are the diagnosis' report rows, the oracle the estimator's
geometry re-identified with the true effect known exactly (:func:`_diagnosis_helpers.oracle_rms`)."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.dataset import read_dataset, write_dataset
from twin.diagnosis import DiagnosisError, diagnose, noise_floor, read_diagnosis, row_context, write_diagnosis
from twin.estimator import calibrate

SEEDS = 10


def effect_size(effect, **kw):
    """RMS per coordinate left by a perfect (noise-free) geometric-only calibration, in noise sigmas."""
    ds, _ = H.make_dataset(seed=11, effect=effect, sigma=1e-10, **kw)
    ds = H._replace(ds, noise_position=1e-10)
    cal = calibrate(ds)
    return cal.residuals["validation"]["position_mm"]["rms"] / np.sqrt(3) / (H.SIGMA * 1e3)


def test_noise_floor_from_consecutive_repeats():
    """The pooled spread of consecutive repeats recovers the instrument's sigma within 10 %."""
    ds, _ = H.make_dataset(seed=0)
    nf = noise_floor(ds)
    assert nf.sigma == pytest.approx(H.SIGMA, rel=0.1)
    assert nf.dof >= 300 and "repeats" in nf.source


def test_no_repeats_no_full_rows_and_no_stated_noise_is_refused():
    """Without repeats, rows with all three spheres or a stated noise, diagnosis says what it needs."""
    ds, _ = H.make_dataset(seed=0, repeats_every=10**9)
    seen = ds.sphere_seen.copy()
    seen[:, 2] = False  # the third sphere never seen: no plate distances to measure the instrument with
    ds = H._replace(ds, noise_position=None, sphere_seen=seen)
    with pytest.raises(DiagnosisError, match="repeat some configurations"):
        diagnose(ds)


def test_without_repeats_the_plate_geometry_gives_the_floor():
    """The spread of the three inter-sphere distances over the campaign recovers sigma within 10 %."""
    ds, _ = H.make_dataset(seed=0, repeats_every=10**9)
    nf = noise_floor(H._replace(ds, noise_position=None))
    assert nf.sigma == pytest.approx(H.SIGMA, rel=0.1) and "inter-sphere distances" in nf.source


def test_plate_floor_sees_pose_to_pose_error_that_repeats_miss():
    """An instrument error that changes from pose to pose (but not between repeats) raises the floor to it."""
    ds, _ = H.make_dataset(seed=0, sigma=1e-6)
    rng = np.random.default_rng(5)
    extra = np.zeros_like(ds.spheres)
    k = 0
    while k < ds.n:  # the same extra error for consecutive repeats of one configuration
        j = k + 1
        while j < ds.n and np.array_equal(ds.q[j], ds.q[k]):
            j += 1
        extra[k:j] = rng.normal(0, 4e-6, (1, 3, 3))
        k = j
    nf = noise_floor(H._replace(ds, spheres=ds.spheres + extra, noise_position=None))
    assert nf.components["repeats"]["sigma_mm"] < 1.2e-3
    assert nf.sigma == pytest.approx(np.hypot(1e-6, 4e-6), rel=0.15) and "inter-sphere" in nf.source


def test_without_a_set_column_the_end_of_the_campaign_is_held_out_and_said():
    """Without a set column (and no holdout) diagnosis holds out the last 30 % of the rows and says so; the
    confirmation rows follow every calibration row and the report rows follow every confirmation row."""
    ds, _ = H.make_dataset(seed=0, n=80)
    res = diagnose(H._replace(ds, set=None), generic=False)
    assert any("no set column: held out the last 30 % of the rows in measurement order" in n for n in res.notes)
    conf, rep = res.rows["confirmation"], res.rows["report"]
    assert len(conf) + len(rep) == pytest.approx(0.3 * ds.n, abs=2)
    assert res.before["n_rows"] == len(rep) > 0
    where = {int(p): k for k, p in enumerate(ds.pose_id)}
    cal = [where[int(p)] for p in ds.pose_id if int(p) not in set(conf) | set(rep)]
    assert max(cal) < min(where[p] for p in conf) and max(where[p] for p in conf) < min(where[p] for p in rep)


def test_interleaved_validation_rows_are_moved_to_the_end_and_said():
    """A set column whose validation rows alternate with the calibration rows: the same share is held out at the end
    of the campaign instead, and the notes say why."""
    ds, _ = H.make_dataset(seed=0, n=60)
    res = diagnose(ds, generic=False)
    share = float(np.mean(ds.set == "validation"))
    assert any(f"interleaves its validation rows with the calibration rows in time: held out instead the same share "
               f"({100 * share:.0f} %)" in n for n in res.notes), res.notes
    assert res.held_out["held_out_rows"].startswith("the dataset's 'set' column interleaves")


@pytest.mark.parametrize("bad", [0, -2, 1.5, True])
def test_a_thread_count_that_is_not_a_positive_integer_is_refused(bad):
    """diagnose names ``threads`` and the value when it is not a positive integer, before any work."""
    ds, _ = H.make_dataset(seed=0, n=40)
    with pytest.raises(ValueError, match=r"threads must be a positive integer, got"):
        diagnose(ds, threads=bad)


def test_a_set_column_without_validation_rows_holds_out_the_end_of_the_campaign():
    """A set column with no validation rows (a campaign imported as one set): the diagnosis runs on the last 30 % held
    out, as without a set column, and its notes say why."""
    ds, _ = H.make_dataset(seed=0, n=40)
    res = diagnose(H._replace(ds, set=np.full(ds.n, "calibration", dtype=object)))
    assert any(n.startswith("held-out rows: the 'set' column has no validation rows: held out the last 30 %")
               for n in res.notes)


@pytest.mark.slow
def test_clean_data_raise_few_false_alarms():
    """With no effect, 'structured' is false in at least 9 of 10 seeds (the test's rate is 1 %)."""
    alarms = 0
    for seed in range(10):
        ds, _ = H.make_dataset(seed=100 + seed, n=120)
        res = diagnose(ds)
        alarms += res.structured
        if not res.structured:
            assert res.effects == () and res.after == res.before
    assert alarms <= 1


@pytest.mark.slow
@pytest.mark.parametrize(
    "name,effect",
    [
        ("compliance", H.compliance(1.5)),
        ("backlash", H.backlash()),
        ("cyclic", H.cyclic()),
        ("gear_ratio", H.gear_ratio()),
        ("coupling", H.coupling(8e-4)),
    ],
)
def test_each_joint_effect_is_detected_named_and_removed(name, effect):
    """An undeclared joint effect of >= 3x the noise is detected and named alone (>= 9/10 seeds), before is
    beyond 2x the oracle (>= 9/10) and the extended model's report-row error within 1.2x of the oracle's (median
    over the seeds)."""
    assert effect_size(effect) >= 3.0
    out = []
    for seed in H.rate_seeds(range(3, 3 + SEEDS)):
        ds, truth = H.make_dataset(seed=seed, n=160, effect=effect)
        res = diagnose(ds)
        oracle = H.oracle_rms(ds, truth["delta"], res.held_out["report_pose_ids"])
        out.append({"seed": seed, "named": res.structured and res.effects == (name,),
                    "visible": res.before["position_mm"]["rms"] > 2.0 * oracle,
                    "ratio": res.after["position_mm"]["rms"] / oracle})
    H.tally(out, named=(9, SEEDS), visible=(9, SEEDS), ratio=("median<=", 1.2))


@pytest.mark.slow
def test_thermal_growth_against_recorded_temperature():
    """Link lengths growing with a recorded temperature drift are found as 'thermal' of all lengths with the
    expansion coefficient within 20 % (>= 9/10 seeds)."""
    n = 160
    temp = np.linspace(20.0, 32.0, n)
    scale = 23e-6 * (temp - 20.0) * 1.0  # aluminium-like expansion of every link
    out = []
    for seed in H.rate_seeds(range(4, 4 + SEEDS)):
        ds, _ = H.make_dataset(seed=seed, n=n, effect=("lengths", scale), temp=temp)
        res = diagnose(ds)
        th = [a for a in res.atoms if a["family"] == "thermal"]
        out.append({"seed": seed, "named": res.structured and res.effects == ("thermal",) and len(th) == 1
                    and th[0]["target"] == "all_lengths" and th[0]["values"][0] == pytest.approx(23e-6, rel=0.2)})
    H.tally(out, named=(9, SEEDS))


@pytest.mark.slow
def test_thermal_drift_in_time_without_temperature():
    """Without temp_c, a warm-up drift of the link lengths in time (t_s) is still found as 'thermal' (>= 9/10
    seeds)."""
    n = 160
    t_s = np.linspace(0.0, 3600.0, n)
    scale = 23e-6 * 10.0 * (1.0 - np.exp(-t_s / 1200.0))
    out = []
    for seed in H.rate_seeds(range(9, 9 + SEEDS)):
        ds, _ = H.make_dataset(seed=seed, n=n, effect=("lengths", scale), t_s=t_s)
        res = diagnose(ds)
        out.append({"seed": seed, "named": res.structured and res.effects == ("thermal",)})
    H.tally(out, named=(9, SEEDS))


@pytest.mark.slow
def test_sphere_off_its_nominal_plate_position_is_plate_geometry():
    """One sphere 46 um off its nominal place (not a rigid motion of the plate) is named plate_geometry and the
    inter-sphere distances recovered within 5 um (>= 9/10 seeds; only the non-rigid part is identifiable)."""
    from twin.dataset import default_plate

    off = np.zeros((3, 3))
    off[2] = [30e-6, -30e-6, 20e-6]
    s0 = default_plate().spheres_flange
    out = []
    for seed in H.rate_seeds(range(8, 8 + SEEDS)):
        ds, _ = H.make_dataset(seed=seed, n=160, plate_offset=off)
        res = diagnose(ds)
        d = np.zeros((3, 3))
        for a in res.atoms:
            if a["family"] == "plate_geometry":
                d[int(a["target"][6:])] += a["values"]
        err = max(abs(np.linalg.norm((s0[i] + d[i]) - (s0[j] + d[j])) - np.linalg.norm((s0[i] + off[i]) - (s0[j] + off[j])))
                  for i, j in ((0, 1), (0, 2), (1, 2)))
        out.append({"seed": seed, "named": res.structured and res.effects == ("plate_geometry",), "distances": err < 5e-6})
    H.tally(out, named=(9, SEEDS), distances=(9, SEEDS))


@pytest.mark.slow
def _excess_by_estimator(ds, sigma):
    """The extra scatter per coordinate [mm] beyond ``sigma`` [m] that the estimator's geometric calibration
    leaves on the held-out rows (estimator code only): sqrt(rms^2 - sigma^2) of its residual per coordinate."""
    cal = calibrate(ds)
    rms = cal.residuals["validation"]["position_mm"]["rms"] / np.sqrt(3)
    return float(np.sqrt(max(rms**2 - (sigma / 1e-3) ** 2, 0.0)))


@pytest.mark.slow
def test_unpredictable_excess_is_reported_not_claimed(tmp_path):
    """An effect nothing here can predict (theta2 ~ sin(7 q3 + 3 q4), no term, no neighbour): no structure is
    claimed, the model stays geometric (>= 9/10 seeds), the excess is reported within 25 % of what the
    estimator's geometric fit leaves beyond the noise (>= 9/10), the files say so."""
    out = []
    for seed in H.rate_seeds(range(5, 5 + SEEDS)):
        ds, _ = H.make_dataset(seed=seed, n=160, effect=H.outside())
        res = diagnose(ds)
        u = res.unexplained
        quiet = not res.structured and res.effects == () and res.atoms == ()
        out.append({"seed": seed, "quiet": quiet and u is not None and not u["predictable"],
                    "size": u is not None and u["excess_sigma_mm"] == pytest.approx(_excess_by_estimator(ds, H.SIGMA),
                                                                                     rel=0.25)})
        if quiet:
            assert res.after == res.before
        if seed == 5:
            paths = write_diagnosis(res, tmp_path)
            d = read_diagnosis(paths["diagnosis"])
            assert d["structured"] is res.structured and d["unexplained"]["predictable"] is u["predictable"]
            assert (tmp_path / "residual_vs_joints.png").stat().st_size > 10_000
    H.tally(out, quiet=(9, SEEDS), size=(9, SEEDS))


def _with_repeatability(ds, sigma_m, sigma_rad, seed):
    """Each row's plate moved by its own random rigid displacement (the robot's repeatability: per visit)."""
    from twin.transforms import pose6_to_transform

    rng = np.random.default_rng(seed)
    sph = ds.spheres.copy()
    for k in range(ds.n):
        T = pose6_to_transform(np.concatenate([rng.normal(0, sigma_m, 3), rng.normal(0, sigma_rad, 3)]))
        c = sph[k].mean(axis=0)
        sph[k] = (sph[k] - c) @ T[:3, :3].T + c + T[:3, 3]
    return H._replace(ds, spheres=sph, noise_position=None)


@pytest.mark.slow
def test_repeatability_beyond_the_floor_is_not_structure():
    """Per-visit random displacements 1.6x the instrument noise, no repeats to see them: the excess is real (p <
    1e-6) and reported within 25 % of the injected displacements' RMS per coordinate, but no structure is
    claimed (>= 9/10 seeds)."""
    out = []
    for seed in H.rate_seeds(range(8, 8 + SEEDS)):
        ds, _ = H.make_dataset(seed=seed, n=200, repeats_every=10**9)
        moved = _with_repeatability(ds, 8e-6, 3e-5, seed=seed + 100)
        injected = float(np.sqrt(np.nanmean((moved.spheres - ds.spheres) ** 2))) / 1e-3
        res = diagnose(moved)
        u = res.unexplained
        out.append({"seed": seed, "real": res.test_before.p_value < 1e-6,
                    "quiet": not res.structured and res.atoms == (),
                    "size": u is not None and u["excess_sigma_mm"] == pytest.approx(injected, rel=0.25)})
    H.tally(out, real=(9, SEEDS), quiet=(9, SEEDS), size=(9, SEEDS))


@pytest.mark.slow
def test_a_fast_wander_in_time_is_no_term():
    """A fast random wander of the measurement frame in time (correlated over a few rows: no polynomial, step,
    transient or period follows it): no term is kept (>= 9/10 seeds). Whether it is called structure, predictable
    from the held-out rows just before each (the held-out rows are a block after the rows that fit, so the smoother
    in time is causal: the 4 rows before), is recorded, not asserted: 6/10 seeds for a wander correlated over one or
    two rows (with smoothers on both sides of interleaved held-out rows it was 9/10)."""
    from scipy.ndimage import gaussian_filter1d

    ds, _ = H.make_dataset(seed=7, n=200)
    t = np.arange(ds.n) * 12.0
    out = []
    for seed in H.rate_seeds(range(70, 70 + SEEDS)):
        wander = gaussian_filter1d(np.random.default_rng(seed).standard_normal(ds.n), 1.0)
        sph = ds.spheres.copy()
        sph[:, :, 2] += 0.015e-3 * (wander / wander.std())[:, None]
        res = diagnose(H._replace(ds, t_s=t, spheres=sph))
        u = res.unexplained or {}
        out.append({"seed": seed, "no_term": res.atoms == () and res.candidate_terms == (),
                    "by_time": bool(res.structured and u.get("predictable") and u.get("by") == "time")})
    H.tally(out, no_term=(9, SEEDS))


@pytest.mark.slow
def test_compliance_and_backlash_together_are_both_found():
    """Two effects at once (compliance + backlash) are both named and nothing else (>= 9/10 seeds), median
    after/oracle <= 1.2."""
    both = lambda q, m: H.backlash()(H.compliance(1.5)(q, m), m)  # noqa: E731
    out = []
    for seed in H.rate_seeds(range(6, 6 + SEEDS)):
        ds, truth = H.make_dataset(seed=seed, n=160, effect=both)
        res = diagnose(ds)
        out.append({"seed": seed, "named": set(res.effects) == {"compliance", "backlash"},
                    "ratio": res.after["position_mm"]["rms"] / H.oracle_rms(ds, truth["delta"],
                                                                             res.held_out["report_pose_ids"])})
    H.tally(out, named=(9, SEEDS), ratio=("median<=", 1.2))


def test_cli_writes_diagnosis_files(tmp_path, capsys):
    """twin diagnose on a dataset folder writes the three JSON files the design card pins, and prints the verdict
    and the before/after of diagnosis.json (the report rows, said so)."""
    from twin.cli import main

    ds, _ = H.make_dataset(seed=7, n=80, effect=H.backlash())
    write_dataset(tmp_path / "ds", ds)
    assert read_dataset(tmp_path / "ds").n == ds.n
    assert main(["diagnose", str(tmp_path / "ds"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    d = read_diagnosis(tmp_path / "out" / "diagnosis.json")
    assert (tmp_path / "out" / d["calibration"]).exists() and (tmp_path / "out" / d["calibration_geometric"]).exists()
    assert d["held_out"]["before_after_on"] == "report" and d["before"]["n_rows"] == d["held_out"]["n_report_rows"]
    out = capsys.readouterr().out
    assert f"structured: {d['structured']}" in out and f"{d['after']['position_mm']['rms']:.5f}" in out


def test_stated_noise_larger_than_repeats_becomes_the_floor():
    """Repeats show sensor noise only; an instrument that states a larger error sets the floor (and says why)."""
    ds, _ = H.make_dataset(seed=0)
    nf = noise_floor(H._replace(ds, noise_position=3 * H.SIGMA))
    assert nf.sigma == pytest.approx(3 * H.SIGMA) and nf.source.startswith("dataset.toml") and "repeats:" in nf.source
    nf2 = noise_floor(H._replace(ds, noise_position=0.5 * H.SIGMA))
    assert nf2.sigma == pytest.approx(H.SIGMA, rel=0.1) and "repeats" in nf2.source


def _anisotropic(seed, sd_xyz=(1e-6, 1e-6, 4e-6), n=160):
    """Clean data whose instrument errs from pose to pose (the same for consecutive repeats, which therefore
    cannot see it), worse in depth (z of the measurement frame); no stated noise."""
    ds, _ = H.make_dataset(seed=seed, n=n, sigma=1e-9)
    rng = np.random.default_rng(seed)
    extra = np.zeros_like(ds.spheres)
    k = 0
    while k < ds.n:
        j = k + 1
        while j < ds.n and np.array_equal(ds.q[j], ds.q[k]):
            j += 1
        extra[k:j] = rng.normal(0.0, 1.0, (1, 3, 3)) * np.asarray(sd_xyz)
        k = j
    return H._replace(ds, spheres=ds.spheres + extra, noise_position=None)


def test_plate_floor_resolves_the_depth_axis():
    """The inter-sphere distances over varied plate attitudes give the per-axis error, depth included."""
    nf = noise_floor(_anisotropic(11))
    assert nf.axis_sigma[2] == pytest.approx(4e-6, rel=0.25)
    assert nf.axis_sigma[0] == pytest.approx(1e-6, rel=0.35) and nf.axis_sigma[1] == pytest.approx(1e-6, rel=0.35)


def test_stated_noise_is_spread_over_the_axes_as_the_data_show():
    """One stated figure per coordinate (the RMS over the axes) of a depth-heavy instrument: the floor keeps the
    data's shape, lateral axes near their true error rather than inflated to the stated average."""
    ds = _anisotropic(11)
    rms = float(np.sqrt(np.mean(np.square([1e-6, 1e-6, 4e-6]))))
    nf = noise_floor(H._replace(ds, noise_position=rms))
    assert nf.axis_sigma[0] < 0.6 * rms and nf.axis_sigma[1] < 0.6 * rms
    assert nf.axis_sigma[2] == pytest.approx(4e-6, rel=0.25)
    assert "spread over the axes" in nf.source


@pytest.mark.slow
def test_clean_anisotropic_instrument_with_a_stated_average_raises_no_alarm():
    """The same depth-heavy instrument stating its average error per coordinate: no alarm in at least 9 of 10
    seeds (the floor is spread over the axes as the data show)."""
    rms = float(np.sqrt(np.mean(np.square([1e-6, 1e-6, 4e-6]))))
    alarms = sum(diagnose(H._replace(_anisotropic(20 + s), noise_position=rms)).structured for s in range(SEEDS))
    assert alarms <= 1


@pytest.mark.slow
def test_clean_anisotropic_instrument_raises_no_alarm():
    """A depth-heavy instrument and no effect: no alarm in at least 9 of 10 seeds (an isotropic floor from the
    distances would see only the lateral error and call the depth noise structure)."""
    alarms = sum(diagnose(_anisotropic(20 + s)).structured for s in range(SEEDS))
    assert alarms <= 1


@pytest.mark.slow
def test_a_pose_dataset_is_diagnosed_through_virtual_points(tmp_path):
    """A 6-DOF instrument's poses (x y z rx ry rz, no spheres) with an undeclared cyclic error on joint 2: read
    as three points of the tool frame, the error is named (>= 9/10 seeds), and the extended calibration predicts
    the measured report-row poses to the noise where the geometric one does not (>= 9/10). 330 poses: the report
    block (the last fifth of the held-out visits, 22 rows) measures the noise's RMS to about 10 %."""
    from twin.dataset import read_dataset
    from twin.diagnosis.apply import predict_extended
    from twin.estimator.simulate import simulate_dataset
    from twin.presets import preset_deviation
    from twin.robots import irb1200
    from twin.transforms import pose6_to_transform

    nom = irb1200()
    true = nom.perturbed(preset_deviation("separation_tables_2_4")).with_frames(
        base2meas=pose6_to_transform(np.array([0.2, -0.1, 1.1, 2.0, -0.3, 0.4])))
    out = []
    for seed in H.rate_seeds(range(5, 5 + SEEDS)):
        rng = np.random.default_rng(seed)
        q = H.configurations(rng, 330, nom)
        ds, _ = simulate_dataset(true, H.cyclic(amp_deg=0.01, joint=2, k=2)(q, nom), robot_spec="irb1200",
                                 nominal=nom, kind="pose", noise_position=5e-6, noise_orientation=2e-5, rng=rng)
        sets = np.array(["validation" if k % 3 == 2 else "calibration" for k in range(len(q))], dtype=object)
        write_dataset(tmp_path / f"ds{seed}", H._replace(ds, q=q, set=sets))
        ds = read_dataset(tmp_path / f"ds{seed}")
        res = diagnose(ds)
        rows = np.isin(ds.pose_id, res.held_out["report_pose_ids"])
        ctx = row_context(ds)

        def pose_rms(pred):
            return np.sqrt(np.mean(np.sum((pred.pose[rows, :3, 3] - ds.pose[rows, :3, 3]) ** 2, axis=1)))

        ext = pose_rms(predict_extended(res.calibration, ctx, ds.station_ids))
        geo = pose_rms(res.calibration_geometric.predict(ds.q, ds.station_ids))
        out.append({"seed": seed, "named": res.effects == ("cyclic",) and any("virtual spheres" in n for n in res.notes),
                    "noise": ext < 1.2 * np.sqrt(3) * 5e-6 and geo > 3 * ext})
    H.tally(out, named=(9, SEEDS), noise=(9, SEEDS))


def test_a_pose_datasets_floor_is_reported_as_the_diagnosis_assumption():
    """Poses read as virtual points get the noise sqrt(sigma_p^2 + (2/3) (L sigma_r)^2) per point coordinate from the
    stated [noise], reported as the diagnosis' assumption (with the stated figures it came from), not as stated."""
    from twin.diagnosis.diagnose import VIRTUAL_ARM, prepare_diagnosis
    from twin.estimator.simulate import simulate_dataset
    from twin.robots import irb1200
    from twin.units import MM_PER_M

    nom = irb1200()
    rng = np.random.default_rng(3)
    q = H.configurations(rng, 90, nom)
    ds, _ = simulate_dataset(nom, q, robot_spec="irb1200", nominal=nom, kind="pose", noise_position=5e-6,
                             noise_orientation=2e-5, rng=rng)
    floor = prepare_diagnosis(H._replace(ds, q=q)).floor
    assumed = floor.components["assumed"]
    want_mm = np.sqrt(5e-6**2 + (2.0 / 3.0) * (VIRTUAL_ARM * 2e-5) ** 2) * MM_PER_M
    assert assumed["sigma_mm"] == pytest.approx(want_mm, rel=1e-12)
    assert assumed["from_stated"] == {"position_mm": pytest.approx(5e-3), "orientation_rad": 2e-5}
    assert "stated" not in floor.components and floor.source.startswith("the diagnosis' assumption")


def test_held_out_rows_split_into_an_earlier_confirmation_and_a_later_report_block():
    """The held-out rows split in two disjoint blocks covering them: the last fifth of the held-out visits report,
    every report row after every confirmation row (a repeat in the block of its visit), no report row with an
    unknown approach history."""
    from twin.diagnosis import split_held_out
    from twin.diagnosis.values import approach_unknown
    from twin.estimator.core import prepare

    ds, _ = H.make_dataset(seed=0, n=120)
    prep = prepare(ds, noise_position=H.SIGMA)
    ctx = row_context(ds)
    held = split_held_out(ds, prep, ctx)
    conf, rep = set(prep.rows[held.confirmation].tolist()), set(prep.rows[held.report].tolist())
    assert not conf & rep and conf | rep == set(prep.rows[prep.val].tolist())
    visits = {}
    for r in sorted(conf | rep):
        visits.setdefault(tuple(np.round(ds.q[r], 9)), set()).add(r in rep)
    assert all(len(v) == 1 for v in visits.values())  # a visit's rows in one block
    n_visits = len(visits)
    assert len([v for v in visits.values() if True in v]) == pytest.approx(n_visits / 5, abs=1)
    assert max(conf) < min(rep)
    assert not approach_unknown(ctx)[sorted(rep)].any()


@pytest.mark.slow
def test_the_named_steps_called_alone_give_what_diagnose_gives():
    """prepare_diagnosis -> fit_geometry -> the test -> atom_pool -> select_terms -> report_before_after, called one
    by one, keep the terms and report the after that diagnose does."""
    from twin.diagnosis import diagnose as run
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis, report_before_after, select_terms

    ds, _ = H.make_dataset(seed=7, n=100, effect=H.backlash())
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    base = fit_geometry(prob, setup.x0)
    assert prob.test(base).p_value < 0.01
    pool, sizes = atom_pool(setup)
    sel = select_terms(prob, base, pool, sizes)
    base = prob.fit(base.z[: setup.prep.space.size], [])
    rep = report_before_after(prob, base, sel.fit)
    res = run(ds)
    assert [a.label for a, _ in sel.fit.chosen] == [a["label"] for a in res.atoms]
    assert rep["after"] == res.after and rep["before"] == res.before

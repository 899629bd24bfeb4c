"""Tests of twin.diagnosis on synthetic sphere-centre data with the instrument's noise (no rendering).

Effects are injected undeclared (nothing about them reaches the dataset but the commanded joints, the row
order and, for thermal growth, the recorded temperature). Sizes are >= 3x the noise after a perfect
geometric-only calibration (``effect_size``)."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.dataset import read_dataset, write_dataset
from twin.diagnosis import DiagnosisError, diagnose, noise_floor, read_diagnosis, row_context, write_diagnosis
from twin.estimator import calibrate


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


def test_without_a_set_column_a_seeded_fraction_is_held_out_and_said():
    """Without a set column (and no holdout) diagnosis holds out a seeded 30 % of the rows and says so."""
    ds, _ = H.make_dataset(seed=0, n=60)
    res = diagnose(H._replace(ds, set=None), generic=False)
    assert any("no 'set' column: held out a seeded random 30 %" in n for n in res.notes)
    assert res.before["n_rows"] == pytest.approx(0.3 * ds.n, abs=1)


def test_a_set_column_without_validation_rows_is_refused():
    """A set column with no validation rows: diagnosis asks for held-out rows."""
    ds, _ = H.make_dataset(seed=0, n=40)
    with pytest.raises(DiagnosisError, match="needs held-out rows"):
        diagnose(H._replace(ds, set=np.full(ds.n, "calibration", dtype=object)))


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
    """An undeclared joint effect of >= 3x the noise is detected, named, and the extended model's validation
    error comes within 1.2x of the error of the true model (geometry + effect) on the same rows."""
    assert effect_size(effect) >= 3.0
    ds, _ = H.make_dataset(seed=3, effect=effect)
    res = diagnose(ds)
    assert res.structured and res.effects == (name,)
    clean, _ = H.make_dataset(seed=3)  # same noise draw, no effect: what the true model achieves
    floor = diagnose(clean).before["position_mm"]["rms"]
    assert res.after["position_mm"]["rms"] <= 1.2 * floor
    assert res.before["position_mm"]["rms"] > 2.0 * floor


@pytest.mark.slow
def test_thermal_growth_against_recorded_temperature():
    """Link lengths growing with a recorded temperature drift are found as 'thermal'."""
    n = 200
    temp = np.linspace(20.0, 32.0, n)
    scale = 23e-6 * (temp - 20.0) * 1.0  # aluminium-like expansion of every link
    eff = ("lengths", scale)
    ds, _ = H.make_dataset(seed=4, n=n, effect=eff, temp=temp)
    res = diagnose(ds)
    assert res.structured and res.effects == ("thermal",)
    (atom,) = [a for a in res.atoms if a["family"] == "thermal"]
    assert atom["target"] == "all_lengths" and atom["values"][0] == pytest.approx(23e-6, rel=0.2)


@pytest.mark.slow
def test_thermal_drift_in_time_without_temperature():
    """Without temp_c, a warm-up drift of the link lengths in time (t_s) is still found as 'thermal'."""
    n = 200
    t_s = np.linspace(0.0, 3600.0, n)
    scale = 23e-6 * 10.0 * (1.0 - np.exp(-t_s / 1200.0))
    ds, _ = H.make_dataset(seed=9, n=n, effect=("lengths", scale), t_s=t_s)
    res = diagnose(ds)
    assert res.structured and res.effects == ("thermal",)


@pytest.mark.slow
def test_sphere_off_its_nominal_plate_position_is_plate_geometry():
    """One sphere 46 um off its nominal place (not a rigid motion of the plate) is named plate_geometry."""
    off = np.zeros((3, 3))
    off[2] = [30e-6, -30e-6, 20e-6]
    ds, _ = H.make_dataset(seed=8, plate_offset=off)
    res = diagnose(ds)
    assert res.structured and res.effects == ("plate_geometry",)
    d = np.zeros((3, 3))
    for a in res.atoms:
        d[int(a["target"][6:])] += a["values"]
    # only the non-rigid part is identifiable: the distances between spheres must match the truth
    from twin.dataset import default_plate

    s0 = default_plate().spheres_flange
    for i, j in ((0, 1), (0, 2), (1, 2)):
        true_d = np.linalg.norm((s0[i] + off[i]) - (s0[j] + off[j]))
        est_d = np.linalg.norm((s0[i] + d[i]) - (s0[j] + d[j]))
        assert abs(est_d - true_d) < 5e-6


@pytest.mark.slow
def test_unpredictable_excess_is_reported_not_claimed(tmp_path):
    """An effect nothing here can predict (theta2 ~ sin(7 q3 + 3 q4), no term, no neighbour): no structure is
    claimed, the excess is reported with its size, the model stays geometric, the files say so."""
    ds, _ = H.make_dataset(seed=5, effect=H.outside())
    res = diagnose(ds)
    assert not res.structured and res.effects == () and res.atoms == ()
    u = res.unexplained
    assert u is not None and not u["predictable"] and u["whitened_rms"] > 3
    assert u["excess_sigma_mm"] == pytest.approx(res.noise.sigma / 1e-3 * np.sqrt(u["whitened_rms"] ** 2 - 1))
    assert res.after == res.before
    paths = write_diagnosis(res, tmp_path)
    d = read_diagnosis(paths["diagnosis"])
    assert d["structured"] is False and d["unexplained"]["predictable"] is False
    assert (tmp_path / "residual_vs_joints.png").stat().st_size > 10_000


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
    """Per-visit random displacements 1.6x the instrument noise, no repeats to see them: the excess is reported
    (within 25 % of its true size) but no structure is claimed."""
    ds, _ = H.make_dataset(seed=8, n=200, repeats_every=10**9)
    res = diagnose(_with_repeatability(ds, 8e-6, 3e-5, seed=3))
    assert res.test_before.p_value < 1e-6  # the excess is real
    assert not res.structured and res.atoms == ()
    assert res.unexplained["excess_sigma_mm"] == pytest.approx(0.0083, rel=0.25)


@pytest.mark.slow
def test_structure_no_term_holds_is_predicted_from_time_neighbours():
    """A fast random wander of the measurement frame in time (correlated over a few rows: no polynomial, step,
    transient or period follows it) is called structure because the nearest rows in time predict held-out rows."""
    from scipy.ndimage import gaussian_filter1d

    ds, _ = H.make_dataset(seed=7, n=200)
    t = np.arange(ds.n) * 12.0
    wander = gaussian_filter1d(np.random.default_rng(70).standard_normal(ds.n), 1.0)
    sph = ds.spheres.copy()
    sph[:, :, 2] += 0.015e-3 * (wander / wander.std())[:, None]
    res = diagnose(H._replace(ds, t_s=t, spheres=sph))
    assert res.structured and res.atoms == ()
    assert res.unexplained["predictable"] and res.unexplained["by"] == "time"
    assert any("predictable from the nearest rows in time" in n for n in res.notes)


@pytest.mark.slow
def test_compliance_and_backlash_together_are_both_found():
    """Two effects at once (compliance + backlash) are both named."""
    both = lambda q, m: H.backlash()(H.compliance(1.5)(q, m), m)  # noqa: E731
    ds, _ = H.make_dataset(seed=6, effect=both)
    res = diagnose(ds)
    assert set(res.effects) == {"compliance", "backlash"}


def test_cli_writes_diagnosis_files(tmp_path, capsys):
    """twin diagnose on a dataset folder writes the three JSON files the design card pins."""
    from twin.cli import main

    ds, _ = H.make_dataset(seed=7, n=80, effect=H.backlash())
    write_dataset(tmp_path / "ds", ds)
    assert read_dataset(tmp_path / "ds").n == ds.n
    assert main(["diagnose", str(tmp_path / "ds"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    d = read_diagnosis(tmp_path / "out" / "diagnosis.json")
    assert d["effects"] == ["backlash"]
    assert (tmp_path / "out" / d["calibration"]).exists() and (tmp_path / "out" / d["calibration_geometric"]).exists()
    for k in ("mean", "rms", "max"):
        assert d["after"]["position_mm"][k] < d["before"]["position_mm"][k]
    assert "structured: True" in capsys.readouterr().out


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
    """The same depth-heavy instrument stating its average error per coordinate: no alarm in at least 4 of 5
    seeds (the floor is spread over the axes as the data show)."""
    rms = float(np.sqrt(np.mean(np.square([1e-6, 1e-6, 4e-6]))))
    alarms = sum(diagnose(H._replace(_anisotropic(20 + s), noise_position=rms)).structured for s in range(5))
    assert alarms <= 1


@pytest.mark.slow
def test_clean_anisotropic_instrument_raises_no_alarm():
    """A depth-heavy instrument and no effect: no alarm in at least 4 of 5 seeds (an isotropic floor from the
    distances would see only the lateral error and call the depth noise structure)."""
    alarms = sum(diagnose(_anisotropic(20 + s)).structured for s in range(5))
    assert alarms <= 1


@pytest.mark.slow
def test_a_pose_dataset_is_diagnosed_through_virtual_points(tmp_path):
    """A 6-DOF instrument's poses (x y z rx ry rz, no spheres) with an undeclared cyclic error on joint 2: read
    as three points of the tool frame, the error is named, and the extended calibration predicts the measured
    validation poses to the noise (the geometric one does not)."""
    from twin.dataset import read_dataset
    from twin.diagnosis.apply import predict_extended
    from twin.estimator.simulate import simulate_dataset
    from twin.presets import preset_deviation
    from twin.robots import irb1200
    from twin.transforms import pose6_to_transform

    rng = np.random.default_rng(5)
    nom = irb1200()
    true = nom.perturbed(preset_deviation("separation_tables_2_4")).with_frames(
        base2meas=pose6_to_transform(np.array([0.2, -0.1, 1.1, 2.0, -0.3, 0.4])))
    q = H.configurations(rng, 220, nom)
    ds, _ = simulate_dataset(true, H.cyclic(amp_deg=0.01, joint=2, k=2)(q, nom), robot_spec="irb1200", nominal=nom,
                             kind="pose", noise_position=5e-6, noise_orientation=2e-5, rng=rng)
    sets = np.array(["validation" if k % 3 == 2 else "calibration" for k in range(len(q))], dtype=object)
    write_dataset(tmp_path / "ds", H._replace(ds, q=q, set=sets))
    ds = read_dataset(tmp_path / "ds")
    res = diagnose(ds)
    assert res.effects == ("cyclic",) and any("virtual spheres" in n for n in res.notes)
    val = ds.set == "validation"
    ctx = row_context(ds)

    def pose_rms(pred):
        return np.sqrt(np.mean(np.sum((pred.pose[val, :3, 3] - ds.pose[val, :3, 3]) ** 2, axis=1)))

    ext = pose_rms(predict_extended(res.calibration, ctx, ds.station_ids))
    geo = pose_rms(res.calibration_geometric.predict(ds.q, ds.station_ids))
    assert ext < 1.2 * np.sqrt(3) * 5e-6 and geo > 3 * ext

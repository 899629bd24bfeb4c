"""The batch: 5 clean, 9 catalogue, 8 outside, 4 mixed campaigns. Shape parameters that are drawn at random
are drawn from the campaign's own generator (factory(rng, info)); amplitudes are set by the target ratio."""

from __future__ import annotations

import numpy as np

import effects as fx
from campaign import Spec


def unit(rng, k=3):
    v = rng.normal(size=k)
    return v / np.linalg.norm(v)


def sign(rng):
    return float(rng.choice([-1, 1]))


SPECS = [
    # ------------------------------------------------------------------ clean
    Spec("clean_isotropic", "clean", n_rows=240, sigma_mm=0.005, temp_col=True, n_missing=3),
    Spec("clean_depth_anisotropic", "clean", n_rows=230, noise_kind="depth", sigma_mm=0.003, depth_factor=3.0,
         repeat_frac=0.2, plate="random"),
    Spec("clean_repeatability_with_repeats", "clean", n_rows=280, sigma_mm=0.004, repeatability_mm=0.012, notes="dataset.toml states the instrument noise only (0.004); robot repeatability is part of the noise; repeats are re-approaches.",
         repeat_frac=0.25, temp_col=True, n_outliers=2),
    Spec("clean_repeatability_no_repeats", "clean", n_rows=260, noise_kind="depth", sigma_mm=0.005, notes="No stated noise; robot repeatability is part of the noise and no repeats reveal it.",
         depth_factor=2.0, repeatability_mm=0.008, set_col=False, n_missing=4, station_col=True,
         station_names=["tracker1"], state_noise=False),
    Spec("clean_multistation_inline_robot", "clean", robot="arm_b", n_rows=300, n_stations=3,
         station_names=["north", "east", "west"], noise_kind="depth", sigma_mm=0.004, depth_factor=2.5,
         repeat_frac=0.15, temp_col=True, plate="random"),
    # ------------------------------------------------------------------ catalogue families
    Spec("compliance_j2_j3_payload", "catalogue", n_rows=260, sigma_mm=0.004, repeat_frac=0.2, temp_col=True,
         temp_rise=(6.0, 9.0),
         effects=[(lambda rng, i: fx.GravityCompliance([2, 3], [1.0, rng.uniform(0.45, 0.7)],
                                                        rng.uniform(1.5, 3.5), [5.0, -10.0, 45.0]), 5.0)],
         expected_names=["compliance"]),
    Spec("backlash_j2_j5_smooth", "catalogue", n_rows=280, n_stations=2, noise_kind="depth", sigma_mm=0.003,
         depth_factor=3.0, n_missing=4,
         effects=[(lambda rng, i: fx.Backlash([2, 5], [1.0, rng.uniform(2.0, 3.0)], transition_deg=0.3,
                                              initial_sign=[1, -1]), 3.0)],
         expected_names=["backlash"], state_noise=False),
    Spec("cyclic_j3_order3", "catalogue", n_rows=240, sigma_mm=0.006, repeat_frac=0.2, set_col=False,
         t_col=False, temp_col=True,
         effects=[(lambda rng, i: fx.Harmonic(3, 3, rng.uniform(0, 360)), 4.0)], expected_names=["cyclic"]),
    Spec("cyclic_motor_side_j4", "catalogue", n_rows=300, sigma_mm=0.003, plate="random",
         effects=[(lambda rng, i: fx.Harmonic(4, 63, rng.uniform(0, 360), side="motor"), 6.0)],
         expected_names=["cyclic"]),
    Spec("gear_ratio_j3_inline_robot", "catalogue", robot="arm_c", n_rows=260, n_stations=2, noise_kind="depth",
         sigma_mm=0.005, depth_factor=2.0, temp_col=True, n_outliers=1,
         effects=[(lambda rng, i: fx.GearRatio(3), 2.5)], expected_names=["gear_ratio"]),
    Spec("coupling_q4_drives_j5", "catalogue", n_rows=240, sigma_mm=0.005, repeatability_mm=0.006,
         repeat_frac=0.2, effects=[(lambda rng, i: fx.Coupling(5, 4), 3.5)], expected_names=["coupling"]),
    Spec("thermal_a3_air_temperature", "catalogue", n_rows=280, sigma_mm=0.003, temp_col=True, n_missing=3,
         temp_rise=(6.0, 9.0),
         effects=[(lambda rng, i: fx.ThermalLink("a", 3, T_ref=20.0, source="air"), 3.0)],
         expected_names=["thermal"]),
    Spec("thermal_d4_lagged", "catalogue", n_rows=300, noise_kind="depth", sigma_mm=0.002, depth_factor=2.5,
         repeat_frac=0.15, temp_col=True, temp_rise=(7.0, 10.0),
         effects=[(lambda rng, i: fx.ThermalLink("d", 4, T_ref=20.0, source="lag", tau_s=rng.uniform(1200, 2400),
                                                 start_offset_k=rng.uniform(0.5, 2.0)), 4.0)],
         expected_names=["thermal"]),
    Spec("plate_sphere_displaced", "catalogue", n_rows=220, sigma_mm=0.006, plate="random", t_col=False,
         effects=[(lambda rng, i: fx.SphereDisplaced(int(rng.integers(0, 3)), unit(rng)), 2.5)],
         expected_names=["plate_geometry"]),
    # ------------------------------------------------------------------ outside the vocabulary
    Spec("hose_hinge_j5", "outside", n_rows=250, sigma_mm=0.004, notes="One-sided quadratic in q5 past +45 deg: not a harmonic, not a scale; partially mimicked by both.",
         effects=[(lambda rng, i: fx.HoseHinge(5, 45.0, side=+1), 4.0)]),
    Spec("base_tilt_gravity_moment", "outside", n_rows=260, noise_kind="depth", sigma_mm=0.004, depth_factor=3.0,
         repeat_frac=0.2, temp_col=True,
         effects=[(lambda rng, i: fx.BaseTiltGravityMoment(rng.uniform(2.0, 4.0), [0.0, 10.0, 55.0]), 3.0)]),
    Spec("forearm_bending", "outside", n_rows=280, n_stations=2, sigma_mm=0.003, n_missing=3,
         effects=[(lambda rng, i: fx.ForearmBending(rng.uniform(1.5, 3.0)), 3.0)]),
    Spec("camera_mount_drift", "outside", n_rows=260, sigma_mm=0.004, temp_col=True, plate="random",
         effects=[(lambda rng, i: fx.CameraMountDrift(unit(rng), unit(rng) / 600.0, rng.uniform(1500, 3000),
                                                      rng.uniform(0, 600)), 5.0)]),
    Spec("base_bump", "outside", n_rows=270, noise_kind="depth", sigma_mm=0.003, depth_factor=2.0,
         repeat_frac=0.2, n_outliers=1,
         effects=[(lambda rng, i: fx.BaseBump(float(i["t"][int(i["n_data"] * rng.uniform(0.55, 0.7))]) - 1.0,
                                              unit(rng), unit(rng) / 800.0), 3.0)]),
    Spec("move_size_offset_j3", "outside", n_rows=240, sigma_mm=0.005, repeat_frac=0.25, set_col=False,
         effects=[(lambda rng, i: fx.MoveSizeOffset(3, 25.0), 4.0)]),
    Spec("bearing_wobble_j1", "outside", n_rows=250, sigma_mm=0.003, temp_col=True, temp_rise=(5.0, 8.0),
         effects=[(lambda rng, i: fx.BearingWobble(4, rng.uniform(0, 360), 200.0), 3.0)]),
    Spec("lens_distortion_residual", "outside", n_rows=260, noise_kind="depth", sigma_mm=0.003, depth_factor=2.5,
         n_missing=3, plate="random", effects=[(lambda rng, i: fx.LensDistortionResidual(), 4.0)]),
    # ------------------------------------------------------------------ mixed
    Spec("mixed_compliance_j235_backlash_j1", "mixed", n_rows=300, sigma_mm=0.004, repeat_frac=0.15,
         temp_col=True,
         effects=[(lambda rng, i: fx.GravityCompliance([2, 3, 5], [1.0, 0.6, 0.08], rng.uniform(2.5, 4.0),
                                                        [15.0, -20.0, 60.0]), 4.0),
                  (lambda rng, i: fx.Backlash([1], [1.0], transition_deg=None, initial_sign=[-1]), 3.0)],
         expected_names=["compliance", "backlash"]),
    Spec("mixed_cyclic_j1_thermal_d4", "mixed", n_rows=280, noise_kind="depth", sigma_mm=0.0025, depth_factor=2.0,
         temp_col=True, n_missing=2, temp_rise=(7.0, 10.0),
         effects=[(lambda rng, i: fx.Harmonic(1, 3, rng.uniform(0, 360)), 3.5),
                  (lambda rng, i: fx.ThermalLink("d", 4, T_ref=20.0, source="air"), 3.0)],
         expected_names=["cyclic", "thermal"]),
    Spec("mixed_product_q2q3_gear_ratio_j6", "mixed", n_rows=260, sigma_mm=0.005, repeat_frac=0.2, notes="Only gear_ratio (joint 6) has a vocabulary name; the q2*q3 term on joint 3 is outside it.",
         effects=[(lambda rng, i: fx.JointProduct(3, 2, 3, 20.0, -60.0), 4.0),
                  (lambda rng, i: fx.GearRatio(6), 3.0)],
         expected_names=["gear_ratio"]),
    Spec("mixed_coupling_q5_j6_camera_drift", "mixed", n_rows=270, sigma_mm=0.004, notes="Only coupling has a vocabulary name; the camera drift (measurement frame, time) is outside it.",
         effects=[(lambda rng, i: fx.Coupling(6, 5), 3.0),
                  (lambda rng, i: fx.CameraMountDrift(unit(rng), unit(rng) / 600.0, rng.uniform(1200, 2500),
                                                      rng.uniform(0, 400)), 3.0)],
         expected_names=["coupling"]),
]

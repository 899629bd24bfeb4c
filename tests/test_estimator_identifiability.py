"""Identifiability analysis: the hand-derived couplings of docs/conventions.md are rediscovered by name."""

import numpy as np
import pytest

from twin.robots import brtirus0707a, irb1200
from twin.estimator.identifiability import analyse_jacobian, preference_order
from twin.estimator.methods import identifiability
from twin.estimator.simulate import random_configurations, simulate_dataset

from _estimator_helpers import camera_base

TMMDH_COUPLINGS = [("d2", "d3"), ("d1", "base_z"), ("d6", "tool_z"), ("a6", "tool_x"),
                   ("theta1", "base_rz"), ("theta6", "tool_rz"), ("alpha6", "tool_rx")]


def _dataset(robot, kind, n=60, seed=0, base=None, q=None):
    make = {"irb1200": irb1200, "brtirus0707a": brtirus0707a}[robot]
    nom = make()
    rng = np.random.default_rng(seed)
    q = random_configurations(nom, n, rng) if q is None else q
    ds, _ = simulate_dataset(nom, q, robot_spec=robot, kind=kind, base2meas={"0": base if base is not None else np.eye(4)},
                             noise_position=1e-5, noise_orientation=1e-4, rng=rng)
    return ds


def test_tmmdh_paper_couplings_for_the_dh_robot():
    """BRTIRUS0707A, 6-DOF poses, base and tool unknown: the TM-MDH paper's seven couplings, 30 of 37 identifiable."""
    ida = identifiability(_dataset("brtirus0707a", "pose"), rows="all")
    assert ida.rank == 30 and len(ida.names) == 37
    for a, b in TMMDH_COUPLINGS:
        c = ida.find(a, b)
        assert c is not None and c.kind == "coupled" and set(c.names) == {a, b}, (a, b, [x.describe() for x in ida.combinations])
        assert abs(abs(c.terms[1][1]) - 1.0) < 1e-9


def test_structure_gauge_drops_the_papers_transformation_parameters():
    """gauge='structure' keeps the robot parameters and drops z, alpha, x', z', alpha', gamma' (TM-MDH 4.2)."""
    ida = identifiability(_dataset("brtirus0707a", "pose"), gauge="structure", rows="all")
    assert set(ida.dropped) == {"d3", "base_z", "base_rz", "tool_x", "tool_z", "tool_rx", "tool_rz"}


def test_mdh_robot_couplings_with_a_camera_base():
    """IRB-1200 (MDH), sphere centres seen from a camera: joint 1's four pre-joint parameters with the base,
    d6 and theta6 with the tool, d2 with d3; 30 of 37 identifiable."""
    base = camera_base(np.random.default_rng(7))
    ida = identifiability(_dataset("irb1200", "spheres", base=base), rows="all")
    assert ida.rank == 30
    for name in ("alpha1", "a1", "d1", "theta1"):
        c = ida.find(name)
        assert c is not None and c.dropped == name and all(n.startswith("base_") for n in c.names[1:])
    assert set(ida.find("d2").names) == {"d2", "d3"}
    assert set(ida.find("d6").names) == {"d6", "tool_z"}
    assert set(ida.find("theta6").names) == {"theta6", "tool_rz"}


@pytest.mark.parametrize("robot,kind", [("irb1200", "spheres"), ("brtirus0707a", "pose")])
def test_orientation_alone_sees_only_theta2_plus_theta3(robot, kind):
    """From orientations alone theta2 and theta3 form one combination (their sum) and no length is seen."""
    ida = identifiability(_dataset(robot, kind), part="orientation", rows="all")
    c = ida.find("theta2", "theta3")
    assert c is not None and set(c.names) == {"theta2", "theta3"}
    assert c.terms[1][1] == pytest.approx(-1.0, abs=1e-9)  # theta2 up, theta3 down: nothing moves
    no_effect = {x.dropped for x in ida.combinations if x.kind == "no_effect"}
    assert {f"d{i}" for i in range(1, 7)} | {f"a{i}" for i in range(1, 7)} <= no_effect


def test_wrist_fixed_at_zero_reports_a_data_dependent_coupling():
    """Joint 5 fixed at 0 (axes 4 and 6 aligned) couples theta4 with theta6's substitute: a rank report names it."""
    rng = np.random.default_rng(3)
    nom = irb1200()
    q = random_configurations(nom, 60, rng)
    q[:, 4] = 0.0
    ida = identifiability(_dataset("irb1200", "spheres", q=q), rows="all")
    assert ida.rank < 30
    c = ida.find("theta4")
    assert c is not None and c.kind == "coupled"


def test_observability_indices_of_known_matrices():
    """Orthogonal columns give condition 1, O1 = 1/sqrt(m), O3 = O4 = 1; two columns at angle phi give
    singular values sqrt(1 +- cos phi) whatever their scale."""
    J = np.zeros((6, 3))
    J[0, 0], J[1, 1], J[2, 2] = 3.0, 1e-4, 7.0
    ida = analyse_jacobian(J, ["a", "b", "c"])
    assert ida.condition_number == pytest.approx(1.0)
    assert ida.O1 == pytest.approx(1 / np.sqrt(6)) and ida.O3 == pytest.approx(1.0) and ida.O4 == pytest.approx(1.0)
    phi = 0.3
    J2 = np.array([[1.0, 5 * np.cos(phi)], [0.0, 5 * np.sin(phi)]])
    ida2 = analyse_jacobian(J2, ["u", "v"])
    assert np.allclose(ida2.singular_values, np.sqrt([1 + np.cos(phi), 1 - np.cos(phi)]))
    assert ida2.condition_number == pytest.approx(np.sqrt((1 + np.cos(phi)) / (1 - np.cos(phi))))


def test_zero_and_duplicate_columns_are_named():
    """A zero column is reported as 'no effect'; a duplicated column as coupled with its twin."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(10, 2))
    J = np.c_[A, np.zeros(10), -2 * A[:, 0]]
    ida = analyse_jacobian(J, ["p", "q", "z", "p2"], order=["p", "q", "z", "p2"])
    assert ida.identifiable == ("p", "q")
    assert ida.find("z").kind == "no_effect"
    c = ida.find("p2")
    assert c.kind == "coupled" and dict(c.terms)["p"] == pytest.approx(2.0)


def test_preference_order_frames_first_and_descending_joints():
    """The frames gauge offers base and tool first, then each family from joint 6 down."""
    names = ["theta1", "theta2", "d1", "d2", "base_x", "tool_x"]
    assert preference_order(names, "frames") == ("base_x", "tool_x", "theta2", "theta1", "d2", "d1")
    assert preference_order(names, "structure") == ("theta1", "theta2", "d1", "d2", "base_x", "tool_x")

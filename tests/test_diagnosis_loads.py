"""Tests of twin.diagnosis.loads: the laws of the arm's own load (a backlash's flank, a compliance stiffening with the
load), the stated masses' torque as a combination of the regressor, the weight of a joint's own link, the base's tilt
per axis, the sign's change at the largest margin, and a carried load beside the stated masses."""

from pathlib import Path

import numpy as np

from twin.diagnosis.atoms import Atom
from twin.diagnosis.candidates import RowContext, gravity_torques
from twin.diagnosis.features import BaseMoment, GravMix, LoadSign, Moment, Torque
from twin.diagnosis.loads import (OWN_LINK_DIRECTIONS, STIFFENING_GRID, STIFFENING_LAWS, STIFFENING_WIDTH, _max_margin,
                                  carried_shapes, fitted_load, law_atom, link_tilt_atom, load_atoms, own_link_atom,
                                  own_link_stiffening, stated_load_mix, stiffening_atoms, tilt_angles, torque_shapes)
from twin.diagnosis.values import feature_values
from twin.robots import irb1200
from twin.urdf import read_urdf_chain

DATA = Path(__file__).resolve().parent.parent / "data" / "tiago_mocap"


def _rows(model, n=80, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.full(model.n_joints, -1.5), np.full(model.n_joints, 1.5)
    return rng.uniform(lo, hi, (n, model.n_joints))


def test_a_load_law_is_a_backlash_up_to_a_third_of_the_loads_rms_and_a_compliance_beyond():
    """The same law of a joint's load is named by its width: the sign or a narrow flank a backlash, a wider one the
    joint's compliance stiffening with its load."""
    model = irb1200()
    base = Atom("backlash", "joint", "theta2", (), "", "", "load", (2,))
    gm = torque_shapes(model, _rows(model), 2, 1)[0]
    assert law_atom(model, base, LoadSign(f=gm), 1.0).family == "backlash"
    assert law_atom(model, base, LoadSign(f=gm, width=0.9 * STIFFENING_WIDTH), 1.0).family == "backlash"
    wide = law_atom(model, base, LoadSign(f=gm, width=1.1 * STIFFENING_WIDTH, law="clip"), 1.0)
    assert wide.family == "compliance" and "stiffening" in wide.label and "clip(" in wide.label
    assert wide.pool == "load"


def test_a_flank_reads_tanh_or_clip_of_the_load_and_the_sign_without_a_width():
    """A load-signed feature reads sign(load), tanh(load / w) or clip(load / w, -1, 1)."""
    model = irb1200()
    q = _rows(model)
    ctx = RowContext(q=q)
    gm = torque_shapes(model, q, 3, 1)[0]
    v = feature_values((gm,), ctx, model)[:, 0]
    got = feature_values((LoadSign(f=gm), LoadSign(f=gm, width=0.3), LoadSign(f=gm, width=0.3, law="clip")), ctx, model)
    assert np.array_equal(got[:, 0], np.sign(v))
    assert np.allclose(got[:, 1], np.tanh(v / 0.3))
    assert np.allclose(got[:, 2], np.clip(v / 0.3, -1, 1))


def test_stated_masses_torque_is_a_combination_of_the_regressor_columns():
    """The stated masses' torque written as one gravmix feature over a joint's regressor columns equals the torque
    the chain's masses give, on every joint that carries one."""
    model = read_urdf_chain(DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link")
    q = _rows(model, 40)
    tau = gravity_torques(model, q)
    ctx = RowContext(q=q)
    checked = 0
    for j in range(1, model.n_joints + 1):
        shapes = torque_shapes(model, q, j, 1)
        if not shapes:
            continue
        v = feature_values((stated_load_mix(model, j, shapes[0].cols),), ctx, model)[:, 0]
        assert np.allclose(v, tau[:, j - 1], atol=1e-9 * max(1.0, np.max(np.abs(tau[:, j - 1]))))
        checked += 1
    assert checked >= 4


def test_the_weight_of_the_upper_arm_is_the_first_harmonic_of_the_shoulder():
    """On the IRB 1200 the compliance under the weight of the link joint 2 moves spans sin q2 and cos q2: the 1st
    harmonic a compliance of joint 2 used to be named beside."""
    model = irb1200()
    q = _rows(model)
    a = own_link_atom(model, q, 2)
    F = feature_values(a.features, RowContext(q=q), model)
    for h in (np.sin(q[:, 1]), np.cos(q[:, 1])):
        c, *_ = np.linalg.lstsq(F, h, rcond=None)
        assert np.max(np.abs(F @ c - h)) < 1e-9
    assert a.family == "compliance" and a.target == "theta2"


def test_the_weight_of_its_own_link_kept_alone_is_the_load_a_stiffening_law_follows():
    """A joint whose compliance is held by the weight of the link it moves alone (no leading torque shapes kept) has
    that fitted deflection as its load: the combination fitted_load returns reproduces it on every row."""
    from types import SimpleNamespace

    model = irb1200()
    q = _rows(model)
    a = own_link_atom(model, q, 2)
    F = feature_values(a.features, RowContext(q=q), model)
    psi = np.array([2e-6, -1e-6])[:F.shape[1]]
    fit = SimpleNamespace(chosen=[(a, np.eye(F.shape[1]))], z=psi, model_cal=SimpleNamespace(offsets=[0, F.shape[1]]))
    load = fitted_load(fit, 2)
    assert isinstance(load, GravMix) and load.i == 2
    v = feature_values((load,), RowContext(q=q), model)[:, 0]
    np.testing.assert_allclose(v, F @ psi, atol=1e-12 * np.max(np.abs(F @ psi)) + 1e-18)


def test_a_link_weights_stiffening_is_offered_along_every_direction_of_its_plane():
    """Without masses, the stiffening of the weight of the link joint 2 moves is offered along directions of that
    weight's plane only, one of them within half a grid step of any direction in it (random directions, seeded): the
    load's zero a stiffening bends about is the link's, wherever a fit placed it."""
    model = irb1200()
    q = _rows(model)
    ctx = RowContext(q=q)
    atoms = own_link_stiffening(model, ctx, 2)
    assert len(atoms) == OWN_LINK_DIRECTIONS * len(STIFFENING_LAWS) * len(STIFFENING_GRID)
    assert {a.family for a in atoms} == {"compliance"} and {a.target for a in atoms} == {"theta2"}
    F = feature_values(own_link_atom(model, q, 2).features, ctx, model)
    loads = np.column_stack([feature_values((a.features[1],), ctx, model)[:, 0] for a in atoms])
    assert np.allclose(F @ np.linalg.lstsq(F, loads, rcond=None)[0], loads, atol=1e-9 * np.max(np.abs(loads)))
    unit = loads / np.linalg.norm(loads, axis=0)
    rng = np.random.default_rng(7)
    for _ in range(20):
        v = F @ rng.normal(size=F.shape[1])
        assert np.max(np.abs(unit.T @ v)) / np.linalg.norm(v) >= np.cos(np.pi / (2 * OWN_LINK_DIRECTIONS)) - 1e-9


def test_a_link_weights_stiffening_is_not_offered_beside_stated_masses():
    """With the chain's masses the stated load's stiffening is in the pool: no directions of a link's weight, on every
    joint whose link's weight spans a plane (TIAGo's joints 3-8)."""
    model = read_urdf_chain(DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link")
    q = _rows(model, 40)
    planar = [j for j in range(1, model.n_joints + 1)
              if (a := own_link_atom(model, q, j)) is not None and len(a.features) == 2]
    assert len(planar) >= 4
    assert all(own_link_stiffening(model, RowContext(q=q), j) == [] for j in planar)


def test_stiffening_atoms_are_compliances_of_both_laws_on_a_grid_of_widths():
    """The stiffening of a known load: compliance atoms of the joint, tanh and clip, each width beyond a backlash's."""
    model = irb1200()
    q = _rows(model)
    atoms = stiffening_atoms(model, RowContext(q=q), 2, torque_shapes(model, q, 2, 1)[0])
    assert {a.family for a in atoms} == {"compliance"} and {a.features[0].law for a in atoms} == {None, "clip"}
    assert len({a.key for a in atoms}) == len(atoms)


def test_a_cross_term_turns_the_pivot_about_the_other_axis():
    """A tilt's features turn the pivot about their ``about`` axis with the coefficient of their ``shape``: the cross
    term of a symmetric compliance turns about x with the moment about y and about y with the moment about x."""
    feats = (Moment(j=0, axis=0, shape=0), Moment(j=0, axis=1, shape=1), Moment(j=0, axis=1, about=0, shape=2),
             Moment(j=0, axis=0, about=1, shape=2))
    M = np.array([[2.0, 3.0], [-1.0, 4.0]])
    F = np.column_stack([M[:, 0], M[:, 1], M[:, 1], M[:, 0]])
    C = np.array([[0.5, 0.2], [0.2, 0.1]])  # cxx, cxy; cxy, cyy
    got = tilt_angles(feats, F, np.array([C[0, 0], C[1, 1], C[0, 1]]))
    assert np.allclose(got, M @ C.T)


def test_the_weight_of_a_link_tilts_the_base_about_both_axes():
    """Without masses, the base's tilt under link 2's first mass moment is a tilt atom of pairs of base-moment
    features (both axes, one coefficient per shape)."""
    model = irb1200()
    a = link_tilt_atom(model, _rows(model), 2)
    assert a.family == "tilt" and a.target == "tilt0" and all(isinstance(f, BaseMoment) for f in a.features)
    assert a.K == len(a.features) // 2


def test_the_sign_change_is_placed_in_the_middle_of_the_gap():
    """Of the directions that put every row on the same side, the one farthest from all of them: rows on a line at
    +-1 and +-3 apart from a gap around 0 give the direction across the gap, not one that grazes a row."""
    V = np.array([[1.0, 0.0], [3.0, 0.5], [-1.0, 0.3], [-3.0, -0.2], [2.0, -0.4], [-2.0, 0.1]])
    u = np.array([1.0, 0.9])  # separates the rows too, close to the rows at +-1
    got = _max_margin(V, u)
    assert np.array_equal(np.sign(V @ got), np.sign(V @ u))
    assert np.min(np.abs(V @ got)) > np.min(np.abs(V @ (u / np.linalg.norm(u)))) + 0.1


def test_the_sign_change_puts_each_row_on_the_flank_its_residual_reads():
    """Given the side each row was read on, the largest margin puts every row there, also those the start direction
    puts on the other side (a direction within fewer shapes that misses rows near zero load)."""
    rng = np.random.default_rng(3)
    V = rng.normal(size=(60, 4))
    sides = np.sign(V @ np.array([1.0, 0.5, -0.3, 0.2]))
    u = np.array([1.0, 0.5, 0.0, 0.0])  # the first two shapes only
    assert np.any(np.sign(V @ u) != sides)
    got = _max_margin(V, u, sides)
    assert np.array_equal(np.sign(V @ got), sides)


def test_a_carried_load_beside_the_stated_masses_is_a_load_of_its_own_pool():
    """With the chain's masses, a joint's load is read as the stated masses' torque (its sign in the catalogue) and as
    that torque with a carried load's leading torque shapes beside it (directions of the pool ``load``), each of unit
    RMS over the rows."""
    model = read_urdf_chain(DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link")
    q = _rows(model, 60)
    ctx = RowContext(q=q)
    j = model.n_joints - 2
    shapes = carried_shapes(model, ctx, j)
    assert len(shapes) == 3
    V = feature_values(shapes, ctx, model)
    assert np.allclose(np.sqrt(np.mean(V ** 2, axis=0)), 1.0)
    assert np.allclose(V[:, 0] * shapes[0].h, gravity_torques(model, q)[:, j - 1])
    mine = [a for a in load_atoms(model, ctx) if a.family == "backlash" and a.target == f"theta{j}"]
    assert {a.pool for a in mine} == {"catalogue", "load"}
    assert [a.features[0].u for a in mine if a.pool == "catalogue"] == [None]

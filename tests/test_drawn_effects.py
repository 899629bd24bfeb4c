"""Drawn instances of every effect family (studies/drawn): the generator, and a small fixed subset of its instances
against each family's targets.

The generator (`studies/drawn/generator`) draws, per seed, the robot, the joint, the size, the timing and the law's
shape of a family, and writes a blind campaign (dataset, answer key, rows after the campaign); it imports no part of
the diagnosis. The rates over 20 draws per family are the benchmark's (`experiments/bench_drawn_effects.py`, section
`drawn_effects`); here a few instances (small campaigns, fixed seeds: the first of `SEEDS` per family in the suite,
all of them under the rate benchmark's `TWIN_FULL_RATES=1`) are a regression check: each must be named right
(`studies/drawn/scoring.py`) with after/oracle within its family's goal (1.2 catalogue, 1.5 outside) on the report rows
and on the rows after the campaign; a clean one must raise no alarm. An instance the diagnosis fails today is a strict
xfail with what was measured (`KNOWN_MISSES`): when it is fixed the test fails until it is taken off the list.
"""

import functools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from _diagnosis_helpers import FULL_RATES  # noqa: E402
from studies.drawn.generator import campaign as C  # noqa: E402
from studies.drawn.generator import families as Fam  # noqa: E402
from studies.drawn.generator.robots import ROBOTS  # noqa: E402
from twin.units import MM_PER_M  # noqa: E402

SMALL = {"rows": (120, 150), "later_rows": (30, 40)}  # the suite's instances: small campaigns, cheap to diagnose


def _sequence(folder: Path) -> dict[str, np.ndarray]:
    """The key's sequence: measured, true and effect points ``(N, K, 3)`` [mm]."""
    import csv

    with open(folder / "key" / "sequence.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    K = sum(1 for c in rows[0] if c.startswith("m") and c.endswith("_x"))
    out = {}
    for pre in "mte":
        out[pre] = np.array([[[float(r[f"{pre}{k}_{a}"]) for a in "xyz"] for k in range(K)] for r in rows])
    return out


def test_the_generator_imports_no_part_of_the_diagnosis():
    """Drawing and writing a campaign loads no module of twin but twin.units (the diagnosis is not among them)."""
    code = ("import sys; from studies.drawn.generator import campaign, make; "
            "print(sorted(m for m in sys.modules if m == 'twin' or m.startswith('twin.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert eval(out) == ["twin", "twin.units"], out


@pytest.mark.parametrize("family", C.FAMILY_ORDER)
def test_a_drawn_key_reproduces_the_data_it_describes(tmp_path, family):
    """The effect recomputed from the key's parameters and the truth file equals the written true minus clean points,
    and the written measured minus true points are the instrument's noise of the drawn size."""
    inst = C.build(family, 7, **SMALL)
    folder = C.write(inst, tmp_path / inst.name)
    seq = _sequence(folder)
    e = C.recompute_effect(folder) * MM_PER_M
    np.testing.assert_allclose(e, seq["e"], atol=2e-6)
    noise = seq["m"] - seq["t"]
    rms = float(np.sqrt(np.mean(np.sum(noise[: inst.n_data] ** 2, axis=-1))))
    if family != "clean":  # the clean family adds its own trouble (correlated noise, gross rows)
        assert rms == pytest.approx(inst.drawn["noise_rms_mm"], rel=1e-3)
    key = json.loads((folder / "key" / "key.json").read_text())
    assert key["category"] == Fam.FAMILIES[family].category and key["drawn"]["family"] == family


def test_a_campaign_of_several_effects_reproduces_each_of_them(tmp_path):
    """Campaigns of several effects (``mixed``, three seeds): two or three families from distinct slots; the written
    effect is the composition of the key's effects recomputed from their parameters, the key names the union of
    their catalogue names, and each effect alone is of its own drawn size."""
    for seed in (7, 8, 9):
        inst = C.build(C.MIXED, seed, **SMALL)
        fams = inst.drawn["families"]
        slots = [next(k for k, v in C.MIXED_SLOTS.items() if f in v) for f in fams]
        assert 2 <= len(fams) <= 3 and len(set(slots)) == len(slots), fams
        folder = C.write(inst, tmp_path / inst.name)
        seq = _sequence(folder)
        np.testing.assert_allclose(C.recompute_effect(folder) * MM_PER_M, seq["e"], atol=2e-6)
        key = json.loads((folder / "key" / "key.json").read_text())
        assert key["category"] == "mixed" and [e["family"] for e in key["effects"]] == fams
        assert key["expected_names"] == sorted({n for f in fams for n in Fam.FAMILIES[f].expected})
        assert [c["ratio_visible"] for c in inst.drawn["components"]] == pytest.approx(
            [c["ratio_drawn"] for c in inst.drawn["components"]], rel=0.01)


def test_campaigns_of_several_effects_draw_every_family():
    """Over 60 campaigns of several effects, every family is drawn, with two and with three effects, never two of a
    slot; their random streams are their own, none of a single family's."""
    seen, counts = set(), set()
    for seed in range(60):
        fams = C._mixed_families(C.streams(C.MIXED, seed)[3])
        slots = [next(k for k, v in C.MIXED_SLOTS.items() if f in v) for f in fams]
        assert len(set(slots)) == len(slots), fams
        seen.update(fams)
        counts.add(len(fams))
    assert seen == set(C.FAMILY_ORDER) - {"clean"} and counts == {2, 3}
    for fam in C.FAMILY_ORDER:
        assert C.streams(C.MIXED, 3)[3].uniform() != C.streams(fam, 3)[3].uniform(), fam


_MIXED_KEY = {"category": "mixed", "expected_names": ["compliance", "tilt"], "effects": [
    {"family": "compliance", "params": {}}, {"family": "tilt", "params": {}},
    {"family": "zero_step", "params": {"joint": 3, "row": 50}}]}


def test_several_effects_are_named_when_every_name_and_change_is_found():
    """A campaign of several effects is named right when the diagnosis names exactly the union of the catalogue
    names and finds every change outside the catalogue; a name missing or extra, or the change missed, is not."""
    from studies.drawn.scoring import family_verdict

    step = {"kind": "step", "target": "theta3", "row": 51}
    ok = {"effects": ["tilt", "compliance"], "changes": [step], "structured": True}
    assert family_verdict(_MIXED_KEY, ok)["named"]
    assert not family_verdict(_MIXED_KEY, {**ok, "effects": ["tilt"]})["named"]
    assert not family_verdict(_MIXED_KEY, {**ok, "effects": ["tilt", "compliance", "thermal"]})["named"]
    assert not family_verdict(_MIXED_KEY, {**ok, "changes": [{**step, "row": 60}]})["named"]
    assert not family_verdict(_MIXED_KEY, {**ok, "changes": [{**step, "minor": True}]})["named"]


def test_several_effects_take_the_goal_of_a_change_outside_the_catalogue_among_them():
    """The after/oracle goal of a campaign of several effects: 1.5 with a change outside the catalogue among them,
    1.2 with catalogue families only."""
    from studies.drawn.scoring import instance_goal

    assert instance_goal(_MIXED_KEY) == 1.5
    assert instance_goal({**_MIXED_KEY, "effects": _MIXED_KEY["effects"][:2]}) == 1.2


def _twin_points(folder: Path) -> np.ndarray:
    """The clean points of a written campaign through twin.kinematics (the library's FK) at the true geometry."""
    from twin.kinematics import RobotModel, flange2base

    ctx, truth, _ = C.read_context(folder)
    p = ctx.params
    beta = {j: float(p["beta"][j - 1]) for j in ctx.robot.beta_joints}
    model = RobotModel.from_tables("x", ctx.robot.convention, theta=p["theta"], d=p["d"], a=p["a"], alpha=p["alpha"],
                                   beta=beta)
    T = ctx.base2meas[ctx.station] @ flange2base(model, ctx.Q) @ np.array(truth["tool2flange"])
    return (np.einsum("nij,kj->nki", T[:, :3, :3], ctx.points_tool) + T[:, None, :3, 3]) * MM_PER_M


def test_the_generators_kinematics_agree_with_the_librarys(tmp_path):
    """The written clean points (true minus effect) equal twin.kinematics' at the true geometry, for an IRB 1200 (MDH)
    and a UR (DH) campaign."""
    seen = {}
    for s in range(40):
        inst = C.build("zero_step", s, **SMALL)
        seen.setdefault(inst.robot.convention, inst)
        if len(seen) == 2:
            break
    assert set(seen) == {"mdh", "dh"}
    for inst in seen.values():
        folder = C.write(inst, tmp_path / inst.name)
        seq = _sequence(folder)
        np.testing.assert_allclose(seq["t"] - seq["e"], _twin_points(folder), atol=2e-5)


@pytest.mark.parametrize("robot,masses", [("irb1200", True), ("ur5", False), ("ur10", True)])
def test_the_stated_robot_is_the_nominal_chain(tmp_path, robot, masses):
    """The dataset's robot (a name, a DH table or a joint table with masses) read by twin.dataset has the generator's
    nominal forward kinematics."""
    from twin.dataset import read_dataset
    from twin.kinematics import flange2base

    rb = ROBOTS[robot]
    for s in range(40):
        inst = C.build("clean", s, **SMALL)
        if inst.robot.name == robot and (inst.masses_stated is not None) == masses:
            break
    else:
        pytest.fail(f"no clean instance of {robot} with masses={masses} in 40 seeds")
    ds = read_dataset(C.write(inst, tmp_path / inst.name) / "dataset")
    q = np.random.default_rng(0).uniform(rb.box[:, 0], rb.box[:, 1], size=(20, 6))
    np.testing.assert_allclose(flange2base(ds.robot, q), rb.frames(rb.params, q)[:, 6], atol=1e-9)


@functools.lru_cache(maxsize=1)
def _contexts() -> tuple:
    """Two fixed campaigns' contexts (an IRB 1200's and a UR10's) to draw instances on."""
    out = []
    for name in ("irb1200", "ur10"):
        inst = next(i for i in (C.build("clean", s) for s in range(40)) if i.robot.name == name)
        out.append(Fam.Ctx(robot=inst.robot, params=inst.params, Q=inst.Q, F=inst.robot.frames(inst.params, inst.Q),
                           t=inst.t, station=inst.station, n_data=inst.n_data, bodies=inst.bodies,
                           base2meas=np.stack([s.base2meas for s in inst.stations]),
                           points_tool=inst.instrument.points_tool, air_c=inst.air_wander_c))
    return tuple(out)


@functools.lru_cache(maxsize=None)
def _draw_many(family: str, n: int = 75) -> list:
    """``n`` draws of ``family``'s instance on each of the two fixed campaigns, no data written: ``(params, ctx)``."""
    out = []
    rng = np.random.default_rng([11, C.FAMILY_ORDER.index(family)])
    for ctx in _contexts():
        k = 0
        while k < n:
            try:
                out.append((Fam.FAMILIES[family].draw(rng, ctx), ctx))
                k += 1
            except Fam.Redraw:
                pass
    return out


def test_draws_cover_the_joints_timings_and_shapes():
    """Over 150 draws per family: every joint where the family can act, every shape and timing, changes from the
    first to the last tenth of the campaign, lags from a few per cent to more than the campaign's span."""
    def values(fam, key):
        return {str(p[key]) for p, _ in _draw_many(fam)}

    for fam in ("backlash_motion", "backlash_size", "zero_step", "zero_glitch", "gear_ratio", "cyclic"):
        assert values(fam, "joint") == {"1", "2", "3", "4", "5", "6"}, fam
    assert values("backlash_load", "joint") >= {"2", "3", "4", "5"}
    assert {j for p, _ in _draw_many("compliance") for j in p["per_joint"]} >= {"2", "3", "4", "5"}
    assert values("compliance", "shape") == {"linear", "stiffening", "two_stiffness"}
    assert values("payload", "timing") == {"on", "off", "window"}
    assert values("backlash_load", "shape") == {"sharp", "smooth"}
    assert values("backlash_size", "shape") == {"saturating", "proportional"}
    assert values("thermal", "profile") == {"ramp", "step"} and values("thermal", "temp_column") == {"True", "False"}
    assert values("frame_change", "kind") == {"knock", "bump", "slip"}
    assert values("coupling", "driven") == {"5", "6"}
    assert {len(p["orders"]) for p, _ in _draw_many("cyclic")} == {1, 2}
    for fam in ("zero_step", "frame_change", "payload"):
        at = [p["row"] / ctx.n_data for p, ctx in _draw_many(fam)]
        assert min(at) < 0.12 and max(at) > 0.85, (fam, min(at), max(at))
    for fam in ("thermal", "motion_heat"):
        lag = [p["tau_s"] / (ctx.t[ctx.n_data - 1] - ctx.t[0]) for p, ctx in _draw_many(fam)]
        assert min(lag) < 0.08 and max(lag) > 0.7, (fam, min(lag), max(lag))


def test_the_size_is_the_drawn_ratio_to_the_noise():
    """Over 12 instances of 4 families, the written effect's part the geometry cannot take over the written noise is
    the drawn ratio (within 1 %), and the ratios drawn reach both ends of 1-20."""
    got = []
    for fam in ("backlash_load", "thermal", "zero_glitch", "tilt"):
        for seed in range(3):
            inst = C.build(fam, seed, **SMALL)
            n = inst.n_data
            B = np.stack([s.base2meas for s in inst.stations])[inst.station]
            U = C.column_basis(C.geometric_jacobian(inst.robot, inst.params, inst.Q[:n], B[:n], inst.station[:n],
                                                   inst.tool2flange, inst.instrument.points_tool))
            vis = C.rms_norm(C.visible_part(U, inst.E[:n])) / C.rms_norm((inst.M - inst.P)[:n])
            assert vis == pytest.approx(inst.drawn["ratio_drawn"], rel=0.01), (fam, seed)
            got.append(vis)
    ratios = [float(np.exp(np.random.default_rng(k).uniform(np.log(C.RATIO[0]), np.log(C.RATIO[1]))))
              for k in range(200)]
    assert min(ratios) < 1.1 and max(ratios) > 18


# ------------------------------------------------------------------------------------------ the fixed subset

SEEDS = (100, 101)
# instances the current diagnosis fails: (family, seed) -> what was measured (the instance in brackets)
KNOWN_MISSES: dict[tuple[str, int], str] = {
    ('payload', 100): "named ['compliance', 'tilt'] not ['compliance'] (joints 2+3, 1.8 kg window rows 80-124/132)",
    ('payload', 101): 'report after/oracle 2.08 > 1.2; later rows after/oracle 5.18 > 1.2 (joints 2+3, 4.0 kg window rows 91-117/125)',
    ('backlash_load', 101): 'later rows after/oracle 2.05 > 1.2 (joint 2, sharp: later rows near zero load outside the campaign\'s configurations put on the wrong flank)',
}


def _params():
    out = []
    for fam in C.FAMILY_ORDER + (C.MIXED,):
        for seed in SEEDS if FULL_RATES else SEEDS[:1]:  # the suite: the first seed of each family
            marks = [pytest.mark.xfail(strict=True, reason=KNOWN_MISSES[(fam, seed)])] if (fam, seed) in KNOWN_MISSES else []
            out.append(pytest.param(fam, seed, marks=marks, id=f"{fam}-{seed}"))
    return out


@pytest.mark.parametrize("family,seed", _params())
def test_a_drawn_instance_meets_its_familys_targets(tmp_path, family, seed):
    """Named right (a clean campaign: no alarm) and after/oracle within the family's goal on the report rows and on
    the rows measured after the campaign."""
    from studies.drawn.scoring import score_instance

    inst = C.build(family, seed, **SMALL)
    folder = C.write(inst, tmp_path / inst.name)
    r = score_instance(folder, tmp_path / "work", in_process=True)
    assert "error" not in r, r.get("error")
    said = (r["effects"], r["changes_found"], r["labels"])
    assert r["named"], said
    assert r["report"]["within_goal"], (r["report"]["after_over_oracle"], said)
    assert r["test"]["within_goal"], (r["test"]["after_over_oracle"], said)


def _scored(tmp_path, family: str, seed: int) -> dict:
    """The drawn instance ``family`` ``seed`` at the suite's small size, scored as the study scores it."""
    return _scored_instance(tmp_path, C.build(family, seed, **SMALL))


def _scored_full(tmp_path, family: str, seed: int) -> dict:
    """The drawn instance ``family`` ``seed`` at the study's full size, scored as the study scores it."""
    return _scored_instance(tmp_path, C.build(family, seed))


def _scored_instance(tmp_path, inst) -> dict:
    from studies.drawn.scoring import score_instance

    return score_instance(C.write(inst, tmp_path / inst.name), tmp_path / "work", in_process=True)


def test_a_ratio_error_beside_other_effects_is_named(tmp_path):
    """A campaign of a ratio error on joint 4 beside a wrist coupling and thermal growth (several effects, seed 15):
    the unnamed product q4*q5 the forward pass keeps at joint 4 gives way to the gear ratio, which predicts the
    held-out rows as well, and every family is named. One regression instance; the rate over 200 drawn campaigns is
    the study's (studies/drawn/results_mixed)."""
    r = _scored_instance(tmp_path, C.build(C.MIXED, 15))
    assert r["drawn"]["families"] == ["thermal", "gear_ratio", "coupling"]
    assert r["named"] and sorted(r["effects"]) == ["coupling", "gear_ratio", "thermal"], r["labels"]
    assert r["test"]["within_goal"], r["test"]["after_over_oracle"]


def test_noise_correlated_in_time_raises_no_alarm(tmp_path):
    """A clean campaign whose instrument frame wanders as an AR(1) over a few rows (rho 0.71, seed 101) is not called
    structured: the held-out smoothers score blocks of time, the time smoother from the block two before."""
    r = _scored(tmp_path, "clean", 101)
    assert r["drawn"]["correlated"]["rho"] > 0.5
    assert not r["structured"] and r["effects"] == [] and r["changes_found"] == []


def test_a_term_of_time_that_follows_a_wander_is_not_confirmed(tmp_path):
    """A clean campaign (seed 212, 283 rows) whose instrument frame wanders as an AR(1) (rho 0.67, 0.59x the noise):
    an oscillation of the measurement frame in time fits the calibration rows and the first held-out rows still
    carry the wander's excursion (signed-rank z 4.8 over rows taken as independent); scored against the rows' serial
    correlation it is not confirmed, and the campaign is not called structured."""
    r = _scored_full(tmp_path, "clean", 212)
    assert r["drawn"]["correlated"]["rho"] > 0.5
    assert not r["structured"] and r["labels"] == [] and r["changes_found"] == []


def test_a_window_that_follows_a_wander_is_not_kept(tmp_path):
    """A clean campaign (seed 400, 274 rows) whose instrument frame wanders as an AR(1) (rho 0.61, 0.44x the noise,
    below the lag-1 test's scatter): a window of joint 2's compliance, then of the measurement frame, gains the
    wander's excursion over a stretch (Delta chi2 127); measured against the scatter the rows outside it show along its
    place (4.5x the floor) it is not significant, and the campaign raises no alarm."""
    r = _scored_full(tmp_path, "clean", 400)
    assert r["drawn"]["correlated"]["rho"] > 0.5
    assert not r["structured"] and r["labels"] == [] and r["changes_found"] == []


def test_a_joints_step_after_the_rows_that_fit_is_confirmed_whatever_the_rows_order(tmp_path):
    """A step of joint 4's zero 44 rows before the end of a campaign (seed 115, 264 rows): a term through the arm is
    scored on rows taken as independent (the poses turn its prediction from row to row), so the rows after the cut
    confirm it (z 4.8 -> 2.7 when it was deflated as a wander, the later rows then 3.3x the oracle)."""
    r = _scored_full(tmp_path, "zero_step", 115)
    assert r["named"], r["changes_found"]
    assert r["test"]["after_over_oracle"] <= 1.5


def test_a_change_in_the_held_out_rows_is_read_by_the_report_rows(tmp_path):
    """A plate slip in the held-out rows (seed 101, row 105 of 128): the report rows read it where every row places
    it, its size from the rows before them, within 1.5x the oracle there (4.7x when they read the calibration rows'
    state)."""
    r = _scored(tmp_path, "frame_change", 101)
    assert r["named"], r["changes_found"]
    assert r["report"]["after_over_oracle"] <= 1.5


def test_the_report_rows_read_a_thermal_term_refitted_on_the_rows_before_them(tmp_path):
    """A drawn thermal instance (seed 5, small): the report rows read the thermal term refitted on every row before
    them, within 1.2x the oracle there (1.64x when they read the calibration rows' fit), and the key says so."""
    r = _scored(tmp_path, "thermal", 5)
    assert r["named"], r["effects"]
    assert r["report"]["after_over_oracle"] <= 1.2
    held = json.loads((tmp_path / "work" / "diagnosis" / "diagnosis.json").read_text())["held_out"]
    assert held["report_state"].startswith("thermal terms refitted")


def test_a_step_of_the_recorded_air_after_the_rows_that_fit_is_thermal_not_a_frame_change(tmp_path):
    """A drawn thermal instance (seed 316, small: the recorded air steps -5.4 K at the last row that fits, a UR10's
    links following it): the step scan's change of the measurement frame after the rows that fit gives way to the
    recorded temperature's change, which explains every row as well with fewer columns: named thermal, within 1.2x the
    oracle on the rows after the campaign (6.5x as a frame change and a payload's before)."""
    r = _scored(tmp_path, "thermal", 316)
    assert r["params"]["temp_column"] and r["params"]["profile"] == "step"
    assert r["named"] and r["changes_found"] == [], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_late_step_of_the_air_without_a_record_is_thermal_not_a_frame_change(tmp_path):
    """A drawn thermal instance (seed 302, full size: the air steps +7.5 K at 0.76 of an IRB 1200's campaign, no
    temperature written, link d1 growing through a short lag): the change of the measurement frame the step scan finds
    after the rows that fit gives way to the air's change, which explains every row as well with fewer parameters (one
    column and three constants against six and one): named thermal, no change."""
    r = _scored_full(tmp_path, "thermal", 302)
    assert not r["params"]["temp_column"] and r["params"]["profile"] == "step"
    assert r["named"] and r["changes_found"] == [], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_one_link_grown_by_one_motors_heat_is_read_with_that_motor(tmp_path):
    """A drawn motion-heat instance (seed 153, small: a UR5's upper arm growing with joint 2's heat alone): named
    thermal against joint 2's heat of that one link, within 1.2x the oracle on the rows after the campaign."""
    r = _scored(tmp_path, "motion_heat", 153)
    assert r["params"]["heat_joints"] == [2] and len(r["params"]["links"]) == 1
    assert r["named"] and len(r["labels"]) == 1 and "joint 2's motion heat" in r["labels"][0], r["labels"]
    assert "all link lengths" not in r["labels"][0]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_wrist_backlash_signed_by_a_load_the_stated_masses_miss_is_named_backlash(tmp_path):
    """A sharp load-signed backlash of joint 4 on an IRB 1200 with a URDF's masses (seed 210, small), whose load the
    instrument's nest it carries sets (the stated masses' sign differs on many rows): named backlash, within 1.2x the
    oracle on the report and later rows (read as the joint's compliance, 3.9x / 4.5x, when only the stated torque's
    sign was offered)."""
    r = _scored(tmp_path, "backlash_load", 210)
    assert r["named"], r["labels"]
    assert r["report"]["after_over_oracle"] <= 1.2 and r["test"]["after_over_oracle"] <= 1.2


def test_a_load_signed_backlash_reads_each_rows_flank_on_every_row(tmp_path):
    """A sharp load-signed backlash of joint 2 at ~19x the noise without masses (seed 217, small): each row's flank read
    from its residual and the sign's change placed in the full span of the torque shapes, the rows after the
    campaign within 1.2x the oracle (28x when a few rows near zero load were left on the wrong flank, set aside as
    gross)."""
    r = _scored(tmp_path, "backlash_load", 217)
    assert r["named"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


@pytest.mark.parametrize("seed", [119, 418])
def test_a_narrow_smooth_flank_seen_by_the_rows_beside_its_change_is_kept(tmp_path, seed):
    """A load-signed backlash whose flank is taken up over a few per cent of the load's RMS (seed 119: UR10 joint 3,
    seed 418: IRB 1200 joint 5, the study's full size), with hardly any calibration row within its middle (``|tanh| <
    0.5``) but several in its shoulders: named backlash with a smooth flank and the rows after the campaign within
    1.2x the oracle (kept as the sign when the middle alone counted, 1.42x / 1.85x)."""
    r = _scored_full(tmp_path, "backlash_load", seed)
    assert r["named"], r["labels"]
    assert "taken up smoothly" in r["labels"][0], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_backlash_taken_up_exponentially_with_the_move_is_read_with_that_law(tmp_path):
    """A backlash of joint 1 taken up as ``1 - exp(-|move| / 14 deg)`` at ~13x the noise (seed 218, small): its law
    refined over tanh, in proportion and the first-order take-up at each one's best width, within 1.2x the oracle on
    the report and later rows (2.0x / 1.4x read as tanh, the nearest of the grid's laws)."""
    r = _scored(tmp_path, "backlash_size", 218)
    assert r["named"], r["labels"]
    assert r["report"]["after_over_oracle"] <= 1.2 and r["test"]["after_over_oracle"] <= 1.2


def test_a_backlash_in_proportion_to_moves_into_every_row_is_named_backlash(tmp_path):
    """A backlash of joint 1 in proportion to its last move up to 49 deg (seed 1, small), the joint moving into every
    row (its step into the row and its last move are the same numbers): no other joint follows its step, so the joint's
    step is read as its backlash, in proportion over the campaign's moves, within 1.2x the oracle on the report and
    later rows."""
    r = _scored(tmp_path, "backlash_size", 1)
    assert r["params"]["shape"] == "proportional"
    assert r["named"] and not any("step into the row" in lab for lab in r["labels"]), r["labels"]
    assert r["report"]["after_over_oracle"] <= 1.2 and r["test"]["after_over_oracle"] <= 1.2


def test_a_backlash_in_proportion_to_moves_saturates_where_the_campaigns_rows_show_it(tmp_path):
    """A backlash of joint 1 in proportion to its last move up to 35 deg (seed 8, small): the calibration rows' moves
    stay short of the bend and a held-out row moves 72 deg; the proportion is not stretched to that row's move (no
    fitted row tested it), and refitted on every row of the campaign the law bends where those rows show it: the rows
    after the campaign within 1.2x the oracle (1.6x in proportion up to the held-out row's move)."""
    r = _scored(tmp_path, "backlash_size", 8)
    assert r["params"]["shape"] == "proportional"
    assert r["named"], r["labels"]
    assert r["report"]["after_over_oracle"] <= 1.2 and r["test"]["after_over_oracle"] <= 1.2


def test_a_stiffening_shoulder_read_as_several_harmonics_is_named_its_compliance(tmp_path):
    """A stiffening compliance of an IRB 1200's joint 2 without masses (seed 216, 280 rows): the weight of the link it
    moves is a first harmonic of its angle and the stiffening adds odd ones, kept first with a function of q2*q3; the
    joint's load read in their place (its torque shapes and link weight, then the stiffening of their sum) predicts
    the confirmation rows as well: named compliance alone, the rows after the campaign within 1.2x the oracle."""
    r = _scored_full(tmp_path, "compliance", 216)
    assert r["params"]["joints"] == [2] and r["params"]["shape"] == "stiffening"
    assert r["effects"] == ["compliance"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_supports_tilt_beside_a_named_compliance_gives_way_to_the_joints_compliance(tmp_path):
    """Compliance of a UR5's joints 3 and 4 with its URDF masses (seed 311): the tilt of joint 5's support about two
    axes (one parallel to joint 4's) entered before joint 4's compliance by a hair; tried in its place, joint 4's
    compliance predicts the confirmation rows as well: one family named, compliance."""
    r = _scored_full(tmp_path, "compliance", 311)
    assert r["params"]["joints"] == [3, 4]
    assert r["effects"] == ["compliance"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_the_bases_tilt_beside_a_payloads_change_gives_way_to_the_joints_compliance(tmp_path):
    """A 6.7 kg payload hung on a UR10 without masses and taken off again (seed 106: joint 2, rows 50-113 of 188): the
    base's tilt under the arm's moment entered before joint 2's compliance by a hair (the rows cannot tell them apart
    about the shoulder's axis); beside the payload's change of joint 2's compliance it is tried as that compliance,
    which predicts the confirmation rows as well: one family named, compliance, the later rows within 1.2x."""
    r = _scored_full(tmp_path, "payload", 106)
    assert r["params"]["joints"] == [2] and r["params"]["timing"] == "window"
    assert r["effects"] == ["compliance"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_supports_tilt_beside_a_payloads_change_gives_way_to_the_joints_compliance(tmp_path):
    """A 3.5 kg payload hung on a UR10 with its URDF's masses and taken off again (seed 517: joint 2, rows 79-134 of
    303): the tilt of joint 1's support (one axis parallel to the shoulder's) read the arm's own weight beside the
    payload's change of joint 2's compliance; tried as that compliance, whose rows it does not predict worse row by
    row: one family named, compliance, the later rows within 1.2x."""
    r = _scored_full(tmp_path, "payload", 517)
    assert r["params"]["joints"] == [2] and r["params"]["timing"] == "window"
    assert r["effects"] == ["compliance"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_payload_taken_off_late_is_not_read_as_an_unrecorded_change_of_the_air(tmp_path):
    """A 1.6 kg payload taken off a UR5 with its URDF's masses 43 rows before the campaign's end (seed 503, no
    temperature written): the change after the rows that fit first read as the air's fast ramp growing one link
    (1.38x the oracle on the later rows); a payload's change of the joints' compliance at that time explains every
    row better: compliance named alone, no thermal term, the later rows within 1.2x."""
    r = _scored_full(tmp_path, "payload", 503)
    assert r["params"]["timing"] == "off" and not r["drawn"]["temp_written"]
    assert r["effects"] == ["compliance"], r["labels"]
    assert not any("thermal" in lab for lab in r["labels"]), r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_payload_hung_on_late_that_the_scan_reads_as_a_frames_step_is_one_event(tmp_path):
    """A 6.8 kg payload hung on a UR10 with a URDF's masses 43 rows before the campaign's end (seed 312, full size),
    which the scan on the rows before the cut reads first as a step of the measurement frame: read as one payload's
    change of joints 2 and 3 at the row it was hung on, the report and later rows within 1.2x the oracle (12.5x later
    when the frame's step stood unconfirmed and the rows were read as unloaded)."""
    r = _scored_full(tmp_path, "payload", 312)
    assert r["named"], r["labels"]
    row = r["params"]["row"]
    assert {c["target"] for c in r["changes_found"]} == {"theta2", "theta3"}, r["changes_found"]
    assert all(abs(c["row"] - row) <= 2 for c in r["changes_found"]), (row, r["changes_found"])
    assert r["report"]["after_over_oracle"] <= 1.2 and r["test"]["after_over_oracle"] <= 1.2


def test_a_frames_bump_in_the_last_rows_with_no_payload_event_is_kept_as_a_step(tmp_path):
    """A station's instrument bumped 20 rows before the end of a 301-row campaign (seed 217, full size), where a
    change of a joint's compliance starts near the step but reads no payload event: the frame's step stands (scored
    again where it still has rows, as it was scored where it has none), named as a change, the later rows within the
    goal."""
    r = _scored_full(tmp_path, "frame_change", 217)
    assert "error" not in r, r.get("error")
    assert r["named"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.5


def test_a_glitchs_window_is_refined_until_its_ends_stop_moving(tmp_path):
    """Joint 2's zero off on 13 rows near the end of a UR5's 263 (seed 509 of zero_glitch, full size): the best window
    is a short one inside the glitch, refined around it until neither end moves, so the zero's window takes every
    glitched row (two rows short, its residual was not white and the compliance's windows at every joint took it):
    named as that one window at the zero, the later rows within the goal."""
    r = _scored_full(tmp_path, "zero_glitch", 509)
    assert r["effects"] == [] and r["named"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.5


def test_a_short_glitch_of_a_joints_zero_is_read_at_the_zero_not_its_compliance(tmp_path):
    """Joint 2's zero off on 5 rows of an IRB 1200's 286 (seed 410 of zero_glitch, full size): the zero's window, judged
    on the rows the compliance's window placed, fits them with one column where the compliance took three; named as
    that one window, no compliance (a payload's window at joints 2 and 3 before)."""
    r = _scored_full(tmp_path, "zero_glitch", 410)
    assert r["effects"] == [] and r["named"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.5



def test_a_zero_step_that_leaves_the_selected_geometry_correlated_is_white_with_the_full_geometry(tmp_path):
    """Joint 3's zero stepped 15 rows before the cut of an IRB 1200's 272 (seed 1004 of zero_step, full size): the
    geometric parameters chosen on rows the step dominated leave the step's residual correlated in time (z 4.5), the
    model's every identifiable direction refitted beside it leaves it white (z -0.1): named as that change, the later
    rows within the goal (read as random scatter, 20x the oracle, while whiteness used the selected geometry only)."""
    r = _scored_full(tmp_path, "zero_step", 1004)
    assert r["effects"] == [] and r["named"], r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_payload_kept_on_is_not_read_as_returning_in_the_campaigns_last_rows(tmp_path):
    """2.2 kg hung on a UR5's flange at row 159 of 251 and never taken off (seed 1114 of payload, full size): a change and
    back of joint 2's compliance ending 17 rows before the campaign's end (fewer than it takes to locate and confirm a
    change there) explains every row no better than the change not ending, against the scatter along its place: the
    rows after the campaign read the loaded state, within 1.2x the oracle (1.46x when the window was kept)."""
    r = _scored_full(tmp_path, "payload", 1114)
    assert r["named"], r["labels"]
    assert all(c["kind"] != "window" for c in r["changes_found"]), r["changes_found"]
    assert r["test"]["after_over_oracle"] <= 1.2


@pytest.mark.parametrize("seed", [108, 711])
def test_a_stiffening_shoulder_of_unknown_masses_is_named_compliance_not_harmonics(tmp_path, seed):
    """A joint 2 stiffening with its load on an IRB 1200 without masses, the load of one sign on most rows (seed 108:
    two stiffnesses, seed 711: smooth; the study's full size): named compliance with a stiffening law and no harmonic,
    the rows after the campaign within 1.2x the oracle (named with joint 2's harmonics when only the fitted torque's
    law was offered: its zero, which the joint's zero takes part of, left the law a line or not admitted)."""
    r = _scored_full(tmp_path, "compliance", seed)
    assert r["named"], r["labels"]
    assert any("stiffening with the load" in label for label in r["labels"]), r["labels"]
    assert not any("harmonic" in label for label in r["labels"]), r["labels"]
    assert r["test"]["after_over_oracle"] <= 1.2


def test_a_payload_taken_off_mid_calibration_is_read_with_its_change(tmp_path):
    """A UR5 (masses stated) whose 4.3 kg payload is taken off at row 65 of 262 (seed 1007, the study's full size): the
    calibration rows hold two load states and the held-out rows one, so the joint's compliance alone fails there and
    no change is found against the geometric fit; kept with the change its rows hold (each confirmed given the other),
    named compliance with the change at row 64, the rows after the campaign within 1.2x the oracle (nothing named
    before, 14.8x)."""
    r = _scored_full(tmp_path, "payload", 1007)
    dj = json.loads((tmp_path / "work" / "diagnosis" / "diagnosis.json").read_text())
    assert any(c["decision"].startswith("kept with a change its rows hold") for c in dj["candidates"]), dj["candidates"]
    assert r["named"], r["labels"]
    assert any(c["kind"] == "step" and abs(c["row"] - 64) <= 2 for c in r["changes_found"]), r["changes_found"]
    assert r["test"]["after_over_oracle"] <= 1.2

"""Tests of twin.diagnosis.refine: its helpers, and the refinement of a change on a campaign."""

import itertools

import numpy as np
import pytest

from twin.diagnosis.refine import clip_value


def test_clip_value_is_np_clip_to_the_bit():
    """``clip_value`` gives ``np.clip``'s number for every order of value and bounds, signed zeros, infinities, NaN
    and bounds the wrong way round."""
    vals = [-2.5, -0.0, 0.0, 1e-300, 0.7, 3.0, np.inf, -np.inf, np.nan, np.float64(0.7)]
    for v, lo, hi in itertools.product(vals, repeat=3):
        got, want = float(clip_value(v, lo, hi)), float(np.clip(v, lo, hi))
        assert np.array_equal(np.array(got), np.array(want), equal_nan=True) and \
            np.signbit(got) == np.signbit(want), (v, lo, hi, got, want)


def _early_step_problem(seed):
    """A campaign whose joint's zero (a drawn joint, 0.01-0.03 deg) steps at a drawn row among its first few, the
    diagnosis' problem on it, its geometric fit, the change's place and the pools' sizes."""
    import _diagnosis_helpers as H
    from twin.diagnosis.changes import change_places
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis

    rng = np.random.default_rng(6100 + seed)
    j, s, b = int(rng.integers(1, 6)), int(rng.integers(1, 5)), rng.uniform(0.01, 0.03) * np.pi / 180

    def eff(q, model):
        out = q.copy()
        out[s:, j] += b
        return out

    ds, _ = H.make_dataset(seed=seed, n=100, effect=eff, t_s=np.cumsum(rng.uniform(8, 12, 125)))
    setup = prepare_diagnosis(ds)
    base = fit_geometry(setup.problem, setup.x0)
    pool, sizes = atom_pool(setup)
    place = next(p for p in change_places(setup.problem.prep.nominal, [a for a in pool if a.pool == "catalogue"])
                 if p.target == f"theta{j + 1}" and p.inner is None)
    return setup.problem, base, place, sizes


@pytest.mark.parametrize("seed", range(3))
def test_a_refined_change_keeps_the_scans_rows_on_each_side_and_its_label_names_its_start(seed):
    """A change of a joint's zero scored at the grid's first decile, where the true step is a few rows from the start:
    the refinement moves it only to times leaving max(MIN_ROWS, MIN_SIDE n) fitting rows before it, and its channel
    and label name the time its features start at."""
    from twin.diagnosis.changes import MIN_ROWS, MIN_SIDE, _atom
    from twin.diagnosis.refine import refine
    from twin.diagnosis.scoring import score_atoms

    prob, base, place, sizes = _early_step_problem(seed)
    t_all = np.asarray(prob.ctx.t_s, float)
    t = np.sort(t_all[prob.rows_cal][prob.w_cal > 0])
    start = float(np.quantile(np.unique(t_all), 0.1))
    scored = score_atoms(prob, base, [_atom(place, "t_s", start, None)], sizes, exact_top=1)[0]
    got = refine(prob, base, scored, sizes)
    at = got.atom.features[0].at
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(t))))
    assert np.sum(t < at) >= side and np.sum(t >= at) >= side, (at, t[:side + 1])
    assert got.atom.channel == f"change(t_s >= {at:.6g})" and got.atom.label.endswith(f"from t_s {at:.6g} on"), \
        got.atom.label

"""The held-out rows as blocks of time (twin.diagnosis.blocks): never interleaved with the rows that fit."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis.blocks import confirm_and_report, held_out_sets, sessions, visits


def _ds(n=60, seed=0, **extra):
    ds, _ = H.make_dataset(seed=seed, n=n, repeats_every=10**9)
    return H._replace(ds, **extra)


def test_validation_rows_at_the_end_are_kept_as_they_are():
    """A set column whose validation rows follow every calibration row is used as it is."""
    ds = _ds()
    s = np.where(np.arange(ds.n) >= 45, "validation", "calibration").astype(object)
    out = held_out_sets(H._replace(ds, set=s))
    assert (out.set == s).all() and out.source == "set column" and not out.registration


def test_interleaved_validation_rows_move_to_the_end_with_their_share():
    """Validation rows alternating with calibration rows: the same share is held out at the end instead, said so."""
    ds = _ds()
    out = held_out_sets(ds)  # make_dataset alternates the rows
    share = float(np.mean(ds.set == "validation"))
    val = np.flatnonzero(out.set == "validation")
    assert val.size == pytest.approx(share * ds.n, abs=1) and val.max() == ds.n - 1
    assert np.all(np.diff(val) == 1) and "interleaves" in out.rule


def test_without_a_set_column_the_last_fraction_is_held_out():
    """No set column: the last `holdout` of the rows, a visit never split."""
    ds, _ = H.make_dataset(seed=1, n=60)  # every 4th pose measured twice in a row
    ds = H._replace(ds, set=None)
    out = held_out_sets(ds, holdout=0.25)
    val = np.flatnonzero(out.set == "validation")
    v = visits(ds)
    assert np.all(np.diff(val) == 1) and val.max() == ds.n - 1
    assert v[val[0]] != v[val[0] - 1]  # the block starts at a visit's first row
    assert val.size == pytest.approx(0.25 * ds.n, abs=2)


def test_whole_sessions_are_held_out_when_a_boundary_is_near_the_fraction():
    """Three sessions, no set column: the last session (about the held-out fraction) is held out whole."""
    ds = _ds(n=89)
    n = ds.n
    sess = np.array(["mon"] * 30 + ["tue"] * 30 + ["wed"] * (n - 60), dtype=object)
    out = held_out_sets(H._replace(ds, set=None, extra={**ds.extra, "session": sess}), holdout=0.3)
    assert (np.flatnonzero(out.set == "validation") == np.arange(60, n)).all() and out.source == "whole sessions"
    assert sessions(H._replace(ds, extra={"session": sess})).tolist() == [0] * 30 + [1] * 30 + [2] * (n - 60)


def test_a_station_seen_only_in_held_out_rows_is_registered_on_its_first_rows():
    """A tracker moved for the held-out session: its first rows (10 % of them, 10 to 50) join the calibration rows
    to register its frame, and the rule names them."""
    ds = _ds(n=200)
    st = np.where(np.arange(ds.n) < 140, "A", "B").astype(object)
    s = np.where(st == "B", "validation", "calibration").astype(object)
    out = held_out_sets(H._replace(ds, station=st, set=s))
    assert out.registration["B"] == [int(p) for p in ds.pose_id[140:150]]
    assert (out.set[140:150] == "calibration").all() and (out.set[150:] == "validation").all()
    assert "station B is measured only in the held-out rows" in out.rule


def test_confirmation_precedes_report_and_the_last_session_reports():
    """Held-out rows of two sessions: the last session reports, the earlier confirms; one session: the last fifth of
    its visits reports; too few visits: no report block."""
    ds = _ds(n=119)
    assert ds.n == 120
    sess = np.repeat(np.array(["a", "b", "c"], dtype=object), 40)
    d2 = H._replace(ds, extra={**ds.extra, "session": sess})
    none = np.zeros(ds.n, bool)
    conf, rep, rule = confirm_and_report(d2, np.arange(40, 120), none)
    assert rep.sum() == 40 and rep[40:].all() and "last held-out session" in rule
    conf, rep, rule = confirm_and_report(ds, np.arange(60, 120), none)
    assert rep.sum() == 12 and rep[-12:].all() and not rep[:-12].any()
    conf, rep, rule = confirm_and_report(ds, np.arange(110, 120), none)
    assert rep is None and conf.all()


def test_holdout_out_of_range_is_refused():
    """A held-out fraction outside [0.05, 0.8] is a ValueError naming it."""
    with pytest.raises(ValueError, match="holdout"):
        held_out_sets(_ds(), holdout=0.9)


def test_a_set_column_without_validation_rows_holds_out_the_end_as_without_one():
    """Every row 'calibration' (an import that wrote the set of one campaign): the end of the campaign is held out,
    the same rows as without a set column, and the rule says why."""
    ds = _ds()
    cal = H._replace(ds, set=np.full(ds.n, "calibration", dtype=object))
    out, none = held_out_sets(cal), held_out_sets(H._replace(ds, set=None))
    assert (out.set == none.set).all() and (out.set[-int(0.3 * ds.n):] == "validation").all()
    assert out.rule.startswith("the 'set' column has no validation rows: held out the last 30 %")


def test_a_holdout_given_replaces_the_set_columns_validation_rows():
    """A set column whose validation rows end the campaign, and holdout 0.2: the last 20 % are held out instead, said
    so (--holdout is always honoured)."""
    ds = _ds()
    s = np.where(np.arange(ds.n) >= 30, "validation", "calibration").astype(object)
    out = held_out_sets(H._replace(ds, set=s), holdout=0.2)
    val = np.flatnonzero(out.set == "validation")
    assert val.size == pytest.approx(0.2 * ds.n, abs=1) and val.max() == ds.n - 1
    assert "the holdout given (0.2) replaces the 'set' column's validation rows" in out.rule

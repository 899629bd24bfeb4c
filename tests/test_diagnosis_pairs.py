"""A term of the arm's load and the change its rows hold, judged together (twin.diagnosis.pairs); the end-to-end case
(a payload taken off mid-calibration, drawn seed 1007) is in tests/test_drawn_effects.py."""

import numpy as np

from twin.diagnosis.atoms import Atom, is_load_term
from twin.diagnosis.features import Gated, LoadSign, Sign, Torque
from twin.diagnosis.pairs import with_change
from twin.diagnosis.scoring import Scored


def _atom(family: str, place: str = "joint", features: tuple = ()) -> Atom:
    return Atom(family, place, "theta2", features, f"{family} channel", f"{family} label", "catalogue", (2,))


def test_the_arms_load_terms_are_a_joints_compliance_a_load_signed_backlash_and_a_supports_tilt():
    """is_load_term: a joint's compliance, a backlash signed by the load and a tilt are terms of the arm's load; a
    backlash signed by the last move, a harmonic, thermal growth and a change of a joint's compliance are not."""
    load = Torque(j=2, h=1.0)
    assert is_load_term(_atom("compliance", features=(load,)))
    assert is_load_term(_atom("backlash", features=(LoadSign(f=load),)))
    assert is_load_term(_atom("tilt", place="param"))
    assert not is_load_term(_atom("backlash", features=(Sign(j=2),)))
    assert not is_load_term(_atom("cyclic"))
    assert not is_load_term(_atom("thermal", place="length"))
    assert not is_load_term(_atom("change", features=(Gated(f=load, ch="t_s", at=10.0, until=None),)))


def test_a_failed_term_not_of_the_arms_load_is_never_fitted_with_a_change():
    """with_change fits nothing for failed tries that hold no load state (a harmonic, a last-move backlash, thermal
    growth): None without touching the problem (a harmonic kept with a payload's window read it 8 rows late)."""
    failed = [Scored(_atom(f, features=feats), np.eye(1), np.zeros(1), 1e4, -50.0, np.zeros(3))
              for f, feats in (("cyclic", ()), ("backlash", (Sign(j=2),)), ("thermal", ()))]
    assert with_change(None, None, failed, [], {}, alpha_select=0.01, z_min=3.0) is None


def test_a_rounds_failed_tries_reach_the_pairing_as_tried_when_two_share_one_label(monkeypatch):
    """select_terms hands pairs.with_change each try that failed on the held-out rows as it was tried: two directions
    of one joint's load-signed backlash (one label, two atoms) reach it as two, not the last scored twice."""
    from types import SimpleNamespace

    from twin.diagnosis import rule
    from twin.diagnosis.confirm import Confirmation

    def backlash(u: tuple) -> Atom:
        return Atom("backlash", "joint", "theta5", (LoadSign(f=Torque(j=5, h=1.0), u=u),), f"load_sign_j5 {u}",
                    "joint 5 backlash (offset signed by its gravity load)", "load", (5,))

    tries = [Scored(backlash(u), np.eye(1), np.zeros(1), 100.0, -20.0, np.zeros(3)) for u in ((1.0, 0.0), (0.0, 1.0))]
    assert tries[0].atom.label == tries[1].atom.label and tries[0].atom.key != tries[1].atom.key
    for name, value in {"score_atoms": lambda *a, **k: list(tries), "prefer_sign": lambda p, f, s, z: s,
                        "prefer_play": lambda p, f, s, z: s, "order_candidates": lambda s: list(s),
                        "distinct_terms": lambda p, o: (list(o), {}), "rival_readings": lambda o, first, m: list(first),
                        "payload_rivals": lambda o, q, m: [], "_implausible": lambda p, s: None,
                        "confirm": lambda p, f, s, z: Confirmation(1.0, 1.0, False),
                        "change_places": lambda *a: ["a place"], "scan_changes": lambda *a, **k: []}.items():
        monkeypatch.setattr(rule, name, value)
    handed = []
    monkeypatch.setattr(rule, "with_change", lambda prob, fit, failed, *a, **k: handed.extend(failed))
    prob = SimpleNamespace(prep=SimpleNamespace(space=np.zeros(0), nominal=None), ctx=SimpleNamespace(q=None),
                           obs_cal=SimpleNamespace(n=100))
    rule.select_terms(prob, None, [tries[0].atom, tries[1].atom], {"change": 1})
    assert [id(s) for s in handed] == [id(s) for s in tries]

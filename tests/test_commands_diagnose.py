"""The words `twin diagnose` prints for the alternative readings it reports (``diagnosis.json`` ``alternatives``)."""

import math

from twin.commands.diagnose import alternative_evidence


def test_an_alternative_judged_on_the_confirmation_rows_prints_their_rms_not_nan():
    """An alternative without a calibration Delta chi2 for both readings (NaN in the library, null in the JSON) is
    printed with the confirmation rows' RMS of the two models, and no 'nan'."""
    for missing in (float("nan"), None):
        d = {"of": "joint 2 compliance under gravity", "alternative": "joint 2, 2nd harmonic", "delta_chi2": missing,
             "delta_chi2_chosen": missing, "share_reproduced": missing, "held_out_rms_mm": [0.040941, 0.040889]}
        words = alternative_evidence(d)
        assert "nan" not in words.lower() and "none" not in words.lower()
        assert "0.04094 mm RMS with it vs 0.04089 mm as kept" in words


def test_an_alternative_with_its_own_delta_chi2_only_prints_it_beside_the_rms():
    """A load term's alternative scored against the model without the kept term prints that Delta chi2 and the
    confirmation rows' RMS, not a Delta chi2 of the kept term it does not have."""
    d = {"delta_chi2": 541.82, "delta_chi2_chosen": math.nan, "held_out_rms_mm": [0.041048, 0.040941]}
    words = alternative_evidence(d)
    assert "delta chi2 542 against the model without the kept term" in words
    assert "0.04105 mm RMS with it vs 0.04094 mm as kept" in words
    assert "nan" not in words.lower()


def test_two_readings_scored_on_the_same_fit_print_both_delta_chi2():
    """Two readings scored on the same fit print their calibration evidence side by side."""
    assert alternative_evidence({"delta_chi2": 7109.2, "delta_chi2_chosen": 7007.8}) == "delta chi2 7109 vs 7008"

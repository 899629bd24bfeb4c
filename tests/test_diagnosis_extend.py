"""The extended model's residuals: an evaluation asked for again is given again, with a fresh evaluation's numbers."""

import numpy as np

import _diagnosis_helpers as H
from twin.diagnosis.diagnose import prepare_diagnosis
from twin.diagnosis.extend import ExtendedModel


def test_residuals_asked_again_are_a_fresh_evaluations_numbers_read_only():
    """ExtendedModel.residuals at a z it evaluated lately gives a fresh evaluation's numbers to the bit, as read-only
    arrays; without the Jacobian those of the evaluation with it; at another z (one bit away) new numbers."""
    ds, _ = H.make_dataset(seed=1, n=60)
    setup = prepare_diagnosis(ds)
    model = setup.problem.model([], "cal")
    z = np.array(setup.x0, dtype=float)
    first = model.residuals(z)
    again = model.residuals(z.copy())
    fresh = model._evaluate(z, True)
    assert again is first
    assert again.r.tobytes() == fresh.r.tobytes() and again.J.tobytes() == fresh.J.tobytes()
    assert not again.r.flags.writeable and not again.J.flags.writeable
    plain = model.residuals(z, jacobian=False)
    assert plain.J is None and plain.r.tobytes() == fresh.r.tobytes()
    z2 = z.copy()
    z2[0] = np.nextafter(z2[0], np.inf)
    moved = model.residuals(z2)
    assert moved is not first and moved.r.tobytes() == model._evaluate(z2, True).r.tobytes()


def test_residuals_of_a_model_gone_are_not_kept():
    """Once its model is gone, a kept evaluation is dropped at the next evaluation (no arrays held for nothing)."""
    import gc

    from twin.diagnosis import extend

    ds, _ = H.make_dataset(seed=1, n=60)
    setup = prepare_diagnosis(ds)
    z = np.array(setup.x0, dtype=float)
    prob = setup.problem
    gone = ExtendedModel(prob.prep.space, prob.obs_cal, [], prob.floor.axis_sigma)  # not one the problem keeps
    gone.residuals(z)
    ref = extend._KEPT.owners()
    del gone
    gc.collect()
    alive = setup.problem.model([], "val")
    alive.residuals(z)
    assert all(r() is not None for r in extend._KEPT.owners())
    assert any(r() is None for r in ref)

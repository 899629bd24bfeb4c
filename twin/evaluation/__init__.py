"""Evaluation: the only layer that reads truth and estimates together (``docs/runner.md``).

* :mod:`.statistics` -- the separation paper's statistics (moved-distance error, eq. 25/43 angle error,
  absolute pose errors, max/mean/RMS/std, improvement) and their aggregation over seeds;
* :mod:`.evaluate` -- a campaign's statistics per method, measured and on the world's truth, and the paper's
  claims;
* :mod:`.report`, :mod:`.targets`, :mod:`.regression` -- tables beside the paper's targets, figures,
  results.json, regression (prediction) bands;
* :mod:`.closeloop` -- the truth beside a diagnosis: synthetic datasets from the world's effects, effect sizes,
  the oracle fit, the true model's error;
* :mod:`.recording` -- the Rerun recording, the only module of the project that imports ``rerun``;
  :mod:`.images` -- the images it (and the runner's resume store) keeps, encoded; :mod:`.workspace` -- a
  diagnosis' held-out rows in the measurement frame for it: the robot's skeleton, the residual vectors, the scales.

The runner (:mod:`twin.runner`) drives a campaign through the layers and hands its truth to this one.
"""

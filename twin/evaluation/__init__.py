"""Evaluation: the only layer that reads truth and estimates together (``docs/runner.md``).

* :mod:`.statistics` -- the separation paper's statistics (moved-distance error, eq. 25/43 angle error,
  absolute pose errors, max/mean/RMS/std, improvement);
* :mod:`.config`, :mod:`.sampling`, :mod:`.plan` -- campaign configs and pose plans in the cameras' view;
* :mod:`.pipeline` -- measurement backends (world renders + instrument measures, or the paper's truth+noise);
* :mod:`.methods` -- the adapter to the estimator's identification methods and compensation;
* :mod:`.executor`, :mod:`.store` -- local processes or Dask behind one interface; atomic per-pose results;
* :mod:`.campaign` -- a campaign end to end (and Monte-Carlo repeats); :mod:`.evaluate` -- its statistics;
* :mod:`.report`, :mod:`.targets`, :mod:`.regression` -- tables beside the paper's targets, figures,
  results.json, regression bands;
* :mod:`.recording` -- the Rerun recording, the only module of the project that imports ``rerun``.
"""

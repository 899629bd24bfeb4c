"""Evaluation: the only layer that reads truth and estimates together.

Statistics of the separation paper (:mod:`.statistics`), campaign configs and pose plans (:mod:`.config`,
:mod:`.sampling`, :mod:`.plan`), the executor layer (:mod:`.executor`), per-pose storage for resume
(:mod:`.store`), the paper's targets (:mod:`.targets`), and the Rerun recording (:mod:`.recording`, the
only module of the project that imports ``rerun``).
"""

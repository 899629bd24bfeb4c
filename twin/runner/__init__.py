"""The runner: one pipeline, plan -> measure -> identify -> diagnose -> compensate -> evaluate (``docs/runner.md``).

* :mod:`.stages` -- the stages, each a function ``stage(state, runtime) -> state`` over a
  :class:`~twin.runner.state.CampaignState` (:mod:`.state`);
* :mod:`.campaign` -- :func:`~twin.runner.campaign.run_campaign` (``twin campaign``: the stages in order) and
  :func:`~twin.runner.campaign.run_repeats` (Monte-Carlo over seeds);
* :mod:`.measure` -- the one render -> measure -> dataset loop (measurement backends, resumable measurement of a
  list of poses, dataset rows); :mod:`.rendered` -- ``twin measure --render``, the measure stage alone;
* :mod:`.config`, :mod:`.sampling`, :mod:`.plan` -- campaign configs and pose plans in the cameras' view;
* :mod:`.methods` -- the adapter to the estimator's identification methods and compensation;
* :mod:`.executor`, :mod:`.store` -- local processes or Dask behind one interface; atomic per-pose results;
* :mod:`.outputs` -- figures, the recording, the diagnosis' verdict as the report stage writes them.

The runner drives every layer; no layer imports it. It holds the world's truth only to hand it to evaluation.
"""

from .campaign import CampaignRun, run_campaign, run_repeats
from .config import CampaignConfig, load_campaign_config, parse_campaign_config
from .rendered import measure_rendered
from .stages import STAGES
from .state import CampaignState, Runtime

__all__ = ["CampaignConfig", "CampaignRun", "CampaignState", "Runtime", "STAGES", "load_campaign_config",
           "measure_rendered", "parse_campaign_config", "run_campaign", "run_repeats"]

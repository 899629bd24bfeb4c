"""The image backend of the measure stage: its stereo calibration, from board views drawn in worker processes
or in this one."""

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import SMALL_TOML  # noqa: E402

from twin.runner.config import parse_campaign_config  # noqa: E402
from twin.runner.executor import open_executor  # noqa: E402
from twin.runner.measure import ImageBackend, backend_spec_for  # noqa: E402

pytestmark = pytest.mark.slow


def _images_config():
    raw = tomllib.loads(SMALL_TOML)
    raw["measurement"]["mode"] = "images"
    raw["world"]["render"]["window_supersample"] = 3
    raw["world"]["board"] = {"views": 8}
    return parse_campaign_config(raw)


def test_board_views_drawn_by_workers_give_the_calibration_drawn_here(tmp_path):
    """The stereo calibration from board views drawn and searched in a worker process is the one from the same
    views drawn in this process (poses and noise from the board seed alone), and the views' truth is recorded
    here either way."""
    cfg = _images_config()
    here = ImageBackend(backend_spec_for(cfg, tmp_path / "here"))
    here.prepare()
    there = ImageBackend(backend_spec_for(cfg, tmp_path / "there"))
    with open_executor("process", 1) as ex:
        there.prepare(ex)
    a, b = here.calibration, there.calibration
    assert a.n_views_used >= 6 and [v.used for v in a.views] == [v.used for v in b.views]
    for x, y in ((a.left, b.left), (a.right, b.right)):
        np.testing.assert_allclose([x.fx, x.fy, x.cx, x.cy, *x.dist], [y.fx, y.fy, y.cx, y.cy, *y.dist],
                                   rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(a.left2right, b.left2right, rtol=0, atol=1e-9)
    assert len(here.world.truth_board_views) == len(there.world.truth_board_views) == len(a.views)
    for (i, T), (j, U) in zip(here.world.truth_board_views, there.world.truth_board_views):
        assert i == j
        np.testing.assert_array_equal(T, U)
    assert (tmp_path / "there" / "stereo_calibration.json").exists()

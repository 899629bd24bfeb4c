"""The test process is a program that runs the twin: it sets the process defaults (off-screen rendering through
EGL, one BLAS thread) before any test module imports numpy or mujoco, as the ``twin`` command does."""

from twin.runtime import set_process_defaults

set_process_defaults()


# The modules holding the suite's longest single tests (a browser session, campaigns of several seeds, a Dask
# cluster, a supersampled render), run first: with `-n 2 --dist worksteal` a long test that starts last runs alone
# while the other core idles. Python's sort is stable, so every module keeps its own tests' order and the rest keep
# theirs.
_LONG_FIRST = ("test_recording_browser.py", "test_regression_matched.py", "test_campaign_regression.py",
               "test_campaign_run.py", "test_world_render.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: k for k, name in enumerate(_LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(_LONG_FIRST)))

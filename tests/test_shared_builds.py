"""The suite's build-once helpers (tests/_shared.py) that the test workers share."""

from _shared import build_if_unclaimed, built_once, session_root


def test_a_claimed_build_is_not_built_again(tmp_path_factory):
    """build_if_unclaimed builds an unclaimed name once and returns False for it afterwards; built_once then reads it."""
    calls = []

    def build(out):
        calls.append(out.name)
        out.write_text("x")

    assert build_if_unclaimed(tmp_path_factory, "shared-test-a", build)
    assert not build_if_unclaimed(tmp_path_factory, "shared-test-a", build)
    assert built_once(tmp_path_factory, "shared-test-a", build).read_text() == "x"
    assert calls == ["shared-test-a"]


def test_a_worker_that_would_wait_runs_meanwhile_first(tmp_path_factory):
    """built_once on a name another worker holds calls ``meanwhile`` before it waits for the 'done' marker."""
    root = session_root(tmp_path_factory)
    (root / "shared-test-b.lock").mkdir()
    (root / "shared-test-b").write_text("y")
    seen = []

    def meanwhile():
        seen.append(True)
        (root / "shared-test-b.done").touch()  # the other worker finishes

    out = built_once(tmp_path_factory, "shared-test-b", lambda p: None, meanwhile=meanwhile)
    assert seen == [True] and out.read_text() == "y"

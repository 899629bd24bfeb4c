"""The provenance every benchmark section and results file carries."""

import json

from twin.benchio import PROVENANCE_PACKAGES, REPOSITORY, command_line, provenance, update_benchmark_section


def test_provenance_names_versions_cpu_and_load():
    """The provenance block holds the CPU model, the load average and a version for each result-changing package."""
    p = provenance(load_at_start=(1.0, 2.0, 3.0))
    assert set(p["packages"]) == set(PROVENANCE_PACKAGES)
    assert p["packages"]["numpy"] and p["packages"]["mujoco"]
    assert p["cpu_count"] >= 1 and isinstance(p["cpu_model"], str)
    assert len(p["load_average_1_5_15"]) == 3
    assert p["load_average_at_start_1_5_15"] == [1.0, 2.0, 3.0]


def test_benchmark_section_carries_the_machine_with_versions(tmp_path):
    """update_benchmark_section stamps its section with versions and load, and leaves other sections alone."""
    f = tmp_path / "bench.json"
    update_benchmark_section("a", {"x": 1}, f)
    update_benchmark_section("b", {"y": 2}, f)
    d = json.loads(f.read_text())
    assert d["a"]["x"] == 1 and d["b"]["y"] == 2
    assert d["a"]["machine"]["packages"]["numpy"]
    assert d["b"]["machine"]["load_average_1_5_15"] is not None


def test_alternate_with_commit_runs_the_earlier_commit_and_the_working_tree_in_turn(tmp_path):
    """Each round runs the earlier commit's files (git archive), then the working tree, each with its own empty
    scratch folder; the hashes returned are the commit's and HEAD's."""
    import subprocess

    from twin.benchio import alternate_with_commit

    repo = tmp_path / "repo"
    repo.mkdir()
    git = dict(cwd=repo, check=True, capture_output=True)
    subprocess.run(["git", "init", "-q"], **git)
    for text in ("old", "new"):
        (repo / "code.txt").write_text(text)
        subprocess.run(["git", "add", "code.txt"], **git)
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", text], **git)
    (repo / "code.txt").write_text("working")
    seen = []

    def run(tree, scratch):
        seen.append(scratch)
        assert not any(scratch.iterdir())
        return {"text": (tree / "code.txt").read_text()}

    sha, head, runs = alternate_with_commit("HEAD~1", 2, run, repo)
    rev = lambda r: subprocess.run(["git", "rev-parse", "--short", r], text=True, **git).stdout.strip()  # noqa: E731
    assert (sha, head) == (rev("HEAD~1"), rev("HEAD"))
    assert [(r["code"], r["text"]) for r in runs] == [(sha, "old"), ("current", "working")] * 2
    assert len(set(seen)) == 4


def test_command_line_records_no_folder_of_the_machine(tmp_path):
    """Absolute paths in a recorded command become repository-relative inside it and OUTSIDE/<name> outside it."""
    assert not tmp_path.is_relative_to(REPOSITORY)
    args = ["studies/x/run.py", "--out", str(tmp_path / "reg.json"), f"--work={tmp_path / 'regwork'}",
            str(REPOSITORY / "results" / "a.json"), "a b"]
    assert command_line("python", args) == ("python studies/x/run.py --out OUTSIDE/reg.json --work=OUTSIDE/regwork "
                                            "results/a.json 'a b'")

"""The provenance every benchmark section and results file carries."""

import json

from twin.benchio import PROVENANCE_PACKAGES, provenance, update_benchmark_section


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

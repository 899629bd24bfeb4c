"""Paper targets: reading, dotted paths, and the ``[[unscored]]`` flags of slips and synthetic entries."""

import math

import pytest

from twin.evaluation.report import paper_parameter_value, render_parameter_table
from twin.evaluation.targets import (
    DEFAULT_TMMDH_TARGETS,
    read_targets,
    scored_value,
    target_value,
    unscored_targets,
)
from twin.presets import preset_deviation


def _table5_exact_095() -> set[str]:
    """Table 5 keys whose value is exactly 0.95 x the Table 4 preset (to the paper's 4 decimals)."""
    t5 = read_targets()["simulation"]["table5"]
    dev = preset_deviation("separation_tables_2_4")
    out = set()
    for key, v in t5.items():
        name, unit = key.rsplit("_", 1)
        preset = dev.get(name, 0.0) * (1e3 if unit == "mm" else 180 / math.pi)
        if preset != 0.0 and round(0.95 * preset, 4) == round(v, 4):
            out.add(key)
    return out


def test_separation_flags_are_the_table5_entries_at_095_of_the_preset():
    """The flagged Table 5 entries are exactly those equal to 0.95 x the preset (d1 and a1 among them)."""
    flagged = {p.rsplit(".", 1)[1] for p in unscored_targets(read_targets()) if p.startswith("simulation.table5.")}
    assert flagged == _table5_exact_095()
    assert {"d1_mm", "a1_mm"} <= flagged


def test_scored_value_drops_flagged_and_keeps_the_rest():
    """scored_value is None for a flagged target and the number for an unflagged one."""
    t = read_targets()
    assert scored_value(t, "simulation.table5.d1_mm") is None
    assert scored_value(t, "simulation.table5.d4_mm") == pytest.approx(-0.0952)
    assert target_value(t, "simulation.table5.d1_mm") == pytest.approx(0.285)


def test_tmmdh_flags_name_the_slips():
    """The TM-MDH file flags a6 and x' (-0.01 mm) and alpha5 (0.00087 rad), and nothing else."""
    t = read_targets(DEFAULT_TMMDH_TARGETS)
    u = unscored_targets(t)
    assert set(u) == {"table6.a[5]", "table7.tool[0]", "table6.alpha[4]"}
    assert target_value(t, "table6.a[5]") == -0.01 and target_value(t, "table7.tool[0]") == -0.01
    assert target_value(t, "table6.alpha[4]") == 0.00087
    assert scored_value(t, "table6.alpha[3]") == -0.0014


def test_parameter_table_marks_flagged_paper_values():
    """The parameter table prints a flagged paper value with '^' and an unflagged one without."""
    t = read_targets()
    params = {"m": {k: {"true": 0.0, "identified": 0.0, "estimated": True} for k in ("d1_mm", "d4_mm")}}
    lines = render_parameter_table(params, t).splitlines()
    d1 = next(ln for ln in lines if ln.startswith("d1_mm"))
    d4 = next(ln for ln in lines if ln.startswith("d4_mm"))
    assert "0.2850^" in d1 and "^" not in d4
    assert paper_parameter_value(t, "d1_mm", scored_only=True) is None
    assert paper_parameter_value(t, "d1_mm") == pytest.approx(0.285)


@pytest.mark.parametrize("entry, message", [
    ('path = "simulation.table5.nope"\nunscored = true\nreason = "x"', "does not resolve"),
    ('path = "simulation.table5.d1_mm"\nunscored = true\nreason = ""', "reason"),
    ('path = "simulation.table5.d1_mm"\nunscored = false\nreason = "x"', "unscored must be true"),
    ('path = "simulation.table5"\nunscored = true\nreason = "x"', "must name a number"),
])
def test_read_targets_rejects_bad_unscored_entries(tmp_path, entry, message):
    """A malformed [[unscored]] entry is a ValueError naming the file and the problem."""
    p = tmp_path / "t.toml"
    p.write_text(f'schema_version = 1\n[simulation.table5]\nd1_mm = 0.285\n\n[[unscored]]\n{entry}\n')
    with pytest.raises(ValueError, match=message) as exc:
        read_targets(p)
    assert str(p) in str(exc.value)

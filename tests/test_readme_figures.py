"""Every figure listed in tests/readme_figures.toml is in README.md and equals, as rounded there, the value
its result file holds (a regenerated result with a stale README sentence fails)."""

import json
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TABLE = tomllib.loads((ROOT / "tests" / "readme_figures.toml").read_text())["figure"]


def _lookup(d, key):
    """The value at dotted ``key``; a dict key may itself hold dots (the longest one that exists is taken)."""
    parts = key.split(".")
    while parts:
        if isinstance(d, list):
            d, parts = d[int(parts[0])], parts[1:]
            continue
        for n in range(len(parts), 0, -1):
            if ".".join(parts[:n]) in d:
                d, parts = d[".".join(parts[:n])], parts[n:]
                break
        else:
            raise KeyError(f"{key!r}: no key {parts[0]!r}")
    return d


def _format(fmt: str, v) -> str:
    s = fmt.format(v)
    return s.replace("%", " %") if fmt.endswith("%}") else s


@pytest.mark.parametrize("fig", TABLE, ids=[f["key"] for f in TABLE])
def test_readme_figure_matches_its_result_file(fig):
    """The quoted sentence is in the README and holds the file's value as the README rounds it."""
    readme = (ROOT / "README.md").read_text()
    assert fig["quote"] in readme, f"README no longer says {fig['quote']!r}"
    value = _lookup(json.loads((ROOT / fig["file"]).read_text()), fig["key"])
    assert _format(fig["fmt"], value) in fig["quote"], (fig["file"], fig["key"], value, fig["quote"])

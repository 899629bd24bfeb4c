"""Every figure on the README and on the pages listed in tests/readme_figures.toml comes from a committed result
file: each quoted passage is on its page, and each number in it, as a whole token, equals the value its file
holds as the page rounds it; on README.md, no number stands outside a declared passage."""

import json
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TABLE = tomllib.loads((ROOT / "tests" / "readme_figures.toml").read_text())["figure"]

# A number as a reader sees one: optional sign, digits, decimals, exponent, possibly followed by "x" (a ratio).
# Not a piece of a word, name or version (IRB-1200, q2, p0_x, v0.41, 4.0.0, 2x2), so that a figure is matched
# whole and never as a part of another token.
NUMBER = re.compile(r"(?<![\w.])(?<!\w-)[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?=x\b|[^\w.]|\.(?!\d)|$)")


# A number right after one of these words names a part of a paper or page, not a measured figure.
REFERENCE = re.compile(r"(?:Figures?|Fig\.|Tables?|[Ss]ections?|eq\.)\s+$")


def _figures(text: str):
    """The number matches of ``text`` that are figures (not references to a table, figure or section)."""
    return [m for m in NUMBER.finditer(text) if not REFERENCE.search(text[max(0, m.start() - 12):m.start()])]


def numbers(text: str) -> list[str]:
    """The number tokens of ``text``, in order."""
    return [m.group(0) for m in _figures(text)]


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


def _expected(v: dict) -> str:
    """The token a value entry stands for: a literal (with its reason) or a file's value formatted."""
    if "literal" in v:
        assert v.get("why"), f"literal {v['literal']!r} needs a 'why'"
        return v["literal"]
    value = _lookup(json.loads((ROOT / v["file"]).read_text()), v["key"])
    if "where" in v:  # the one element of a list whose fields match, found by its names, never by its position
        hits = [x for x in value if all(x.get(k) == w for k, w in v["where"].items())
                and not any(k in x for k in v.get("absent", ()))]
        assert len(hits) == 1, f"{v['file']}:{v['key']}: {len(hits)} elements match {v['where']}"
        value = _lookup(hits[0], v["then"])
    if "scale" in v:
        value = value * v["scale"]
    return v["fmt"].format(value)


def _page_text(page: str) -> str:
    return (ROOT / page).read_text()


def _id(fig) -> str:
    return f"{fig.get('page', 'README.md')}:{fig['quote'][:60]}"


def problems(fig: dict, text: str | None = None) -> list[str]:
    """What is wrong with one declared passage: absent from its page, or its numbers not its files' values."""
    page = fig.get("page", "README.md")
    text = _page_text(page) if text is None else text
    if fig["quote"] not in text:
        return [f"{page} no longer says {fig['quote']!r}"]
    got = numbers(fig["quote"])
    want = [tok for v in fig["values"] for tok in numbers(_expected(v))]  # a value such as "29/29" is two tokens
    return [] if got == want else [f"{page}: numbers {got} in {fig['quote']!r}, files say {want}"]


@pytest.mark.parametrize("fig", TABLE, ids=[_id(f) for f in TABLE])
def test_each_number_of_a_quoted_passage_is_its_files_value(fig):
    """The passage is on its page and its number tokens are, one for one and in order, the declared values."""
    assert problems(fig) == []


def _uncovered(text: str, quotes: list[str]) -> list[str]:
    """Numbers of ``text`` outside code and link targets that lie in no quoted passage."""
    covered = [False] * len(text)
    for q in quotes:
        start = 0
        while (i := text.find(q, start)) >= 0:
            covered[i:i + len(q)] = [True] * len(q)
            start = i + 1
    for pat in (r"```.*?```", r"`[^`\n]*`", r"\]\([^)]*\)"):  # code blocks, inline code, link targets
        for m in re.finditer(pat, text, flags=re.S):
            covered[m.start():m.end()] = [True] * (m.end() - m.start())
    out = []
    for m in _figures(text):
        if not all(covered[m.start():m.end()]):
            line = text.count("\n", 0, m.start()) + 1
            out.append(f"line {line}: {m.group(0)!r} in {text.splitlines()[line - 1].strip()[:90]!r}")
    return out


def test_every_number_on_the_readme_is_declared():
    """No number on README.md stands outside a passage whose numbers are checked against a result file."""
    quotes = [f["quote"] for f in TABLE if f.get("page", "README.md") == "README.md"]
    bad = _uncovered(_page_text("README.md"), quotes)
    assert not bad, "README numbers without a declared source:\n" + "\n".join(bad)


def test_number_tokens_are_whole():
    """The tokeniser takes whole numbers: not the digits inside names, versions or larger numbers."""
    assert numbers("IRB-1200 at 0.0047 mm, q2 and t_s, 9/10 seeds, p = 1.6e-15, 12.0 / 4.23") == \
        ["0.0047", "9", "10", "1.6e-15", "12.0", "4.23"]
    assert numbers("rerun v0.41, mujoco 4.0.0 and 2x2 windows, 3.1x the oracle.") == ["3.1"]
    assert numbers("the paper's Figure 10 and Tables 9-11 give 0.0197") == ["0.0197"]


def test_a_stale_figure_fails():
    """A passage whose last number differs from its file's value in the last printed digit is caught."""
    fig = next(f for f in TABLE if any("file" in v for v in f["values"]))
    token = numbers(fig["quote"])[-1]
    stale_token = token[:-1] + ("1" if token[-1] != "1" else "2")
    i = fig["quote"].rindex(token)
    stale = {**fig, "quote": fig["quote"][:i] + stale_token + fig["quote"][i + len(token):]}
    assert problems(stale, text=stale["quote"]) != []


def test_a_number_outside_every_passage_is_reported():
    """A figure on the page that no declared passage covers is found; code and link targets are not figures."""
    text = "We reach 3.5 mm here, see [it](studies/x_2/README.md) and `twin calibrate --prior-mm 0.5`.\n"
    bad = _uncovered(text, [])
    assert len(bad) == 1 and bad[0].startswith("line 1: '3.5'")
    assert _uncovered(text, ["reach 3.5 mm"]) == []

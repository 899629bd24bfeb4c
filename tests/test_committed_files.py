"""The committed files hold no folder of the machine that wrote them and no link out of the repository."""

import re
import sys
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# an absolute path of a machine: a temporary folder, a home, a checkout or tool folder (not one inside a relative
# path such as studies/**/work/ or OUT/work/)
MACHINE_PATH = re.compile(r"(?<![\w.*~-])/(tmp|work|root|home|Users|mnt|opt|srv|scratch|private|var|usr)/")
# (file, text on the line): the few absolute paths that belong where they are
ALLOWED = {
    (".ci/run", "#!/usr/bin/env bash"),  # the interpreter line
    ("Makefile", "/usr/lib/*/dri/swrast_dri.so"),  # the system's Mesa driver, checked by make sysdeps
    # the distribution's own interpreter, preferred by make install and compared with another by the environment study
    ("Makefile", "for p in /usr/bin/python3 python3;"),
    ("studies/environment/README.md", "--pythons /usr/bin/python3"),
    ("studies/environment/interpreters.py", "--pythons /usr/bin/python3"),
    # the robot description's own header, as PAL's xacro wrote it (the vendor's file, kept unchanged)
    ("data/tiago_mocap/tiago_48_schunk.urdf", "/opt/pal/ferrum/share/tiago_description/robots/tiago.urdf.xacro"),
}
SELF = "tests/test_committed_files.py"  # this file names the paths it allows and holds the checker's example
MARKDOWN_LINK = re.compile(r"\]\(([^)\s]+)\)")


def _tracked() -> list[str]:
    r = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=False)
    if r.returncode != 0:
        pytest.skip("not a git checkout")
    return [f for f in r.stdout.decode().split("\0") if f]


def _text(rel: str) -> str | None:
    """The file's text, None for a binary file (a NUL byte) or one absent from the work tree."""
    p = ROOT / rel
    if not p.is_file():
        return None
    data = p.read_bytes()
    return None if b"\0" in data[:8192] else data.decode("utf-8", errors="replace")


def machine_paths(files: list[str]) -> list[str]:
    """``file:line: text`` of every absolute machine path in ``files`` (relative to the repository) not allowed."""
    out = []
    for rel in files:
        text = None if rel == SELF else _text(rel)
        if text is None:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if MACHINE_PATH.search(line) and not any(rel == f and t in line for f, t in ALLOWED):
                out.append(f"{rel}:{n}: {line.strip()[:160]}")
    return out


def links_out(files: list[str]) -> list[str]:
    """``file:line: target`` of every relative markdown link of ``files`` that leaves the repository or names a
    file that is not there; links to web pages (``https://``) are fine."""
    out = []
    for rel in files:
        text = _text(rel)
        if text is None:
            continue
        for m in MARKDOWN_LINK.finditer(text):
            target = m.group(1)
            if re.match(r"[a-z][a-z0-9+.-]*:|#", target):
                continue
            dest = (ROOT / rel).parent.joinpath(target.split("#")[0]).resolve()
            if not dest.is_relative_to(ROOT) or not dest.exists():
                out.append(f"{rel}:{text[:m.start()].count(chr(10)) + 1}: {target}")
    return out


def test_no_committed_file_holds_a_machine_path():
    """No tracked text file (code, docs, results) holds an absolute folder of a machine, besides the allow-list."""
    assert machine_paths(_tracked()) == []


def test_docs_link_only_inside_the_repository():
    """Every relative link of the tracked markdown files (docs, README, the studies' READMEs) resolves inside it."""
    assert links_out([f for f in _tracked() if f.endswith(".md")]) == []


def test_checkers_catch_a_machine_path_and_a_link_out(tmp_path, monkeypatch):
    """A temporary folder's path in a results file and a ../../ link out of the repository are reported with file and
    line."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    out = "/".join(("", "tmp", "reg.json"))  # a machine's temporary folder, assembled so that this file names none
    (tmp_path / "r.json").write_text('{\n "command": "python x.py --out ' + out + '",\n "dir": "studies/**/work/"\n}\n')
    (tmp_path / "a.md").write_text("see [the card](../../shared/DESIGN.md) and [b](b.md), [web](https://x.org)\n")
    (tmp_path / "b.md").write_text("[back](a.md)\n")
    assert machine_paths(["r.json"]) == [f'r.json:2: "command": "python x.py --out {out}",']
    assert links_out(["a.md", "b.md"]) == ["a.md:1: ../../shared/DESIGN.md"]

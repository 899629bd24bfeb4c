"""Write drawn campaigns: python -m studies.drawn.generator.make --out DIR [--families all] [--seeds 0-19]

Each instance goes to ``DIR/<family>_<seed>/`` (``dataset/``, ``key/``); deterministic from the family and the seed
(``campaign.py``). Prints one line per instance: what was drawn.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from .campaign import FAMILY_ORDER, MIXED, build, write

__all__ = ["main", "parse_seeds", "parse_families"]


def parse_seeds(text: str) -> list[int]:
    """``"0-19"``, ``"3"`` or ``"1,4,7"`` -> the seeds; ``ValueError`` naming the text."""
    out: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part:
                a, b = part.split("-")
                out += list(range(int(a), int(b) + 1))
            elif part.strip():
                out.append(int(part))
    except ValueError:
        raise ValueError(f"seeds must be like 0-19 or 1,4,7, got {text!r}") from None
    if not out or min(out) < 0:
        raise ValueError(f"seeds must be like 0-19 or 1,4,7, got {text!r}")
    return out


def parse_families(text: str) -> list[str]:
    """The families of ``text`` (comma-separated; ``all``: every family of ``FAMILY_ORDER``; ``mixed``, several
    effects at once, only when named)."""
    fams = list(FAMILY_ORDER) if text == "all" else [f.strip() for f in text.split(",") if f.strip()]
    bad = [f for f in fams if f not in FAMILY_ORDER and f != MIXED]
    if bad:
        raise ValueError(f"unknown families {bad}; known: {list(FAMILY_ORDER) + [MIXED]}")
    return fams


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--families", default="all")
    ap.add_argument("--seeds", default="0-2")
    a = ap.parse_args(argv)
    try:
        fams, seeds = parse_families(a.families), parse_seeds(a.seeds)
    except ValueError as exc:
        ap.error(str(exc))
    for fam in fams:
        for seed in seeds:
            t0 = time.time()
            inst = build(fam, seed)
            write(inst, a.out / inst.name)
            d = inst.drawn
            print(f"{inst.name:<22} {d['robot']:<8} K={d['K']} rows={d['rows']}+{d['later_rows']} "
                  f"ratio={d.get('ratio_drawn', '-')} {time.time() - t0:.1f}s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

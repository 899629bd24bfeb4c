"""The subcommands of ``twin`` (one module each, see :mod:`twin.cli`) and what they share."""

from __future__ import annotations

import sys

__all__ = ["warn_forced"]


def warn_forced(path, reasons: list[str]) -> None:
    """Print, on stderr, that a calibration was written with ``twin calibrate --force`` and why (nothing when
    ``reasons`` is empty)."""
    for r in reasons:
        print(f"warning: {path} was written by `twin calibrate --force` past: {r}; results from it may be wrong",
              file=sys.stderr)

"""The ``twin`` command line. Subcommands follow the data flow; each lives in ``twin/commands/<name>.py``
and exposes ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

__all__ = ["main", "SUBCOMMANDS"]

# In data-flow order. A subcommand is listed once its module exists.
SUBCOMMANDS = (
    "campaign",
    "render",
    "measure",
    "import",
    "calibrate",
    "register",
    "predict",
    "compensate",
    "diagnose",
    "plan",
    "export",
)


def _available() -> list[str]:
    return [name for name in SUBCOMMANDS if importlib.util.find_spec(f"twin.commands.{name}") is not None]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="twin",
        description="Digital-twin testbed for kinematic calibration: world -> instrument -> dataset -> "
        "estimator -> diagnosis -> evaluation.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _available():
        mod = importlib.import_module(f"twin.commands.{name}")
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return 0
    try:
        return int(args._module.run(args) or 0)
    except ValueError as exc:  # bad input: a clear message naming the field, no traceback
        print(f"twin {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path that cannot be used (an --out naming an existing file, no permission, ...)
        where = exc.filename if exc.filename is not None else ""
        print(f"twin {args.command}: error: {where}: {exc.strerror or exc} (check the paths given, e.g. --out)",
              file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

"""The ``twin`` command line. Subcommands follow the data flow; each lives in ``twin/commands/<name>.py``
and exposes ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``.

:func:`console` is the installed command's entry point: it sets the process defaults
(:func:`twin.runtime.set_process_defaults`: off-screen rendering, one BLAS thread) before anything imports numpy
or mujoco, then runs :func:`main`, which itself leaves the environment alone (tests call it in-process).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

from . import __version__

__all__ = ["main", "console", "SUBCOMMANDS", "error_message"]

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
    parser.add_argument("--version", action="version", version=f"twin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _available():
        mod = importlib.import_module(f"twin.commands.{name}")
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def error_message(exc: BaseException) -> str:
    """The one-line message of a bad-input error, naming its subject: a ``ValueError``'s own message (the readers
    name the file, row and field); an ``OSError``'s file(s) and cause; a ``UnicodeDecodeError`` that escaped a
    reader (which would name no file) says what it is."""
    if isinstance(exc, UnicodeDecodeError):
        return f"a file given is not UTF-8 text ({exc.reason} at byte {exc.start}); check the files given"
    if isinstance(exc, OSError):
        names = [str(f) for f in (exc.filename, exc.filename2) if f is not None]
        cause = exc.strerror or str(exc)
        if not names:
            return f"{cause} (check the paths given, e.g. --out)"
        return f"{' -> '.join(names)}: {cause} (check the paths given, e.g. --out)"
    return str(exc)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return 0
    try:
        return int(args._module.run(args) or 0)
    except (ValueError, OSError) as exc:  # bad input or an unusable path: one clear line, no traceback
        print(f"twin {args.command}: error: {error_message(exc)}", file=sys.stderr)
        return 2


def console() -> None:
    """The ``twin`` command: process defaults first (before numpy or mujoco load), then :func:`main`."""
    from .runtime import set_process_defaults

    set_process_defaults()
    sys.exit(main())


if __name__ == "__main__":
    console()

"""The ``wearfit`` command: one subcommand per pipeline job.

Each subcommand lives in ``wearfit_usd/commands/<name>.py`` and exposes
``register(subparsers, common)`` and ``run(args) -> int``. Heavy imports
happen inside ``run`` so that ``wearfit --help`` stays fast.

Exit codes: 0 success, 1 failure, 2 bad input or usage, 130 interrupted.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

from . import __version__
from .errors import WearfitError
from .progress import set_verbosity

COMMANDS = ["inspect", "fit", "dress", "animate", "render", "demo", "batch"]


def common_options() -> argparse.ArgumentParser:
    """Options every subcommand accepts (also after the subcommand name)."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("output")
    g.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="no progress bars or messages (warnings and errors still shown)")
    g.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                   help="more detail; show tracebacks on errors")
    return p


def build_parser() -> argparse.ArgumentParser:
    common = common_options()
    parser = argparse.ArgumentParser(
        prog="wearfit", parents=[common],
        description="Fit wearable items from a reference rigged USD body onto other bodies "
                    "and animate them with motion capture.")
    parser.add_argument("--version", action="version", version=f"wearfit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        mod = importlib.import_module(f"wearfit_usd.commands.{name}")
        mod.register(sub, common)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    quiet = getattr(args, "quiet", False)
    verbose = getattr(args, "verbose", False)
    set_verbosity(0 if quiet else (2 if verbose else 1))
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except WearfitError as exc:
        if verbose:
            traceback.print_exc()
        print(f"wearfit {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"wearfit {args.command}: interrupted", file=sys.stderr)
        return 130
    except (MemoryError, OSError) as exc:
        if verbose:
            traceback.print_exc()
        print(f"wearfit {args.command}: error: {exc}", file=sys.stderr)
        return 1


def console() -> None:  # pragma: no cover - exercised through the installed command
    """Entry point of the installed ``wearfit`` command: run :func:`main`,
    flush, and leave without the interpreter's teardown. Every output is
    written, closed and renamed into place by then; tearing down the loaded
    USD, scipy and numba modules only cost the user another 0.3-0.4 s."""
    rc = main()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed pipe: nothing more to say
        pass
    os._exit(rc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

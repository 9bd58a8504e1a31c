"""The ``wearfit`` command: one subcommand per pipeline job.

Each subcommand lives in ``wearfit_usd/commands/<name>.py`` and exposes
``register(subparsers, common)`` and ``run(args) -> int``. Heavy imports
happen inside ``run`` so that ``wearfit --help`` stays fast.

Exit codes: 0 success, 1 failure, 2 bad input or usage, 130 interrupted.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import traceback
import warnings

from . import __version__
from .errors import WearfitError
from .io.gltf import set_default_pose as set_gltf_pose
from .progress import set_verbosity

COMMANDS = ["inspect", "fit", "dress", "animate", "render", "export", "demo", "batch"]


def common_options() -> argparse.ArgumentParser:
    """Options every subcommand accepts (also after the subcommand name)."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("output")
    g.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="no progress bars or messages (warnings and errors still shown)")
    g.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                   help="more detail; show tracebacks on errors")
    p.add_argument("--gltf-pose", metavar="POSE", default=argparse.SUPPRESS,
                   help=".glb/.gltf characters: the rest pose to read them in: auto (default: of the bind "
                        "pose, the nodes' pose and the animations' first frames, the one closest to the "
                        "references' rest pose), bind (inverse bind matrices), nodes, or an animation's name")
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


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C so that every ``with`` block and
    ``finally`` clause (temporary files, clip folders) cleans up."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum, frame):
    # further SIGTERM/SIGHUP are ignored so that they cannot cut the clean-up
    # short (the handlers are restored when the command returns)
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            signal.signal(sig, signal.SIG_IGN)
    raise Terminated(signum)


@contextlib.contextmanager
def _signals_as_interrupts():
    """SIGTERM and SIGHUP raise :class:`Terminated` in the main thread for
    the duration of the command (previous handlers restored afterwards)."""
    old = {}
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        try:
            old[sig] = signal.signal(sig, _raise_terminated)
        except (ValueError, OSError):  # not the main thread
            pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def _warnings_as_messages(command: str):
    """Python warnings print as ``wearfit CMD: warning: message`` (once
    each), not with the source file and line."""
    def show(message, category, filename, lineno, file=None, line=None):
        out = file or sys.stderr
        try:
            print(f"wearfit {command}: warning: {message}", file=out, flush=True)
        except (OSError, ValueError):
            pass
    old = warnings.showwarning
    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = old


def _pxr_error_message(exc: Exception) -> str | None:
    """The message of a ``pxr.Tf.ErrorException`` (USD's errors), else None."""
    if type(exc).__module__.startswith("pxr") or type(exc).__name__ == "ErrorException":
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        return lines[-1].split(": '", 1)[-1].rstrip("'") if lines else type(exc).__name__
    return None


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    quiet = getattr(args, "quiet", False)
    verbose = getattr(args, "verbose", False)
    set_verbosity(0 if quiet else (2 if verbose else 1))
    set_gltf_pose(getattr(args, "gltf_pose", None))
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        with _signals_as_interrupts(), _warnings_as_messages(args.command):
            return int(args.func(args) or 0)
    except WearfitError as exc:
        if verbose:
            traceback.print_exc()
        print(f"wearfit {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except Terminated as exc:
        name = signal.Signals(exc.signum).name
        print(f"wearfit {args.command}: stopped by {name}; no partial output left", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print(f"wearfit {args.command}: interrupted", file=sys.stderr)
        return 130
    except (MemoryError, OSError) as exc:
        if verbose:
            traceback.print_exc()
        print(f"wearfit {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:
        msg = _pxr_error_message(exc)
        if msg is None:
            raise
        if verbose:
            traceback.print_exc()
        print(f"wearfit {args.command}: error: USD: {msg}", file=sys.stderr)
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

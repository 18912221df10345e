"""The ``bioslam`` command: one module per subcommand, each exposing ``register(subparsers)``.

A subcommand module adds its parser and sets ``func`` to a callable taking the parsed
arguments and returning a dict: the one-line JSON summary printed last on stdout.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import importlib
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from bioslam import __version__, signals

SUBCOMMAND_MODULES = ("info", "sim", "thin", "run", "demo", "eval", "consistency", "batch")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bioslam",
        description="Biologically-inspired 2D LiDAR SLAM: odometry, boundary cells, "
        "pose cells and a cognitive map.",
    )
    parser.add_argument("--version", action="version", version=f"bioslam {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(f"bioslam.cli.{name}").register(subparsers)
    return parser


def print_summary(summary: dict) -> None:
    """Print the machine-readable summary as the last stdout line (strict JSON: NaN and
    infinities become null; anything else not JSON fails loudly)."""
    from bioslam.io.jsonio import dumps_json

    print(dumps_json(summary, indent=None), flush=True)


def main(argv: Sequence[str] | None = None, *, exiting: bool = False) -> int:
    """Run a subcommand; the exit code is described in :mod:`bioslam.cli.common`.

    SIGINT and SIGTERM are handled for the whole command: never a traceback, and a command
    that has started writing results finishes them with ``"interrupted": true``. ``exiting``
    (the ``bioslam`` program) ignores them once the command is done, while the process exits.
    """
    with signals.installed(ignore_after=exiting):
        try:
            return _main(argv)
        except signals.Interrupted as exc:
            # Only reached before a command created any output.
            print(f"bioslam: interrupted by {exc}", file=sys.stderr)
            return exc.exit_code


def _main(argv: Sequence[str] | None) -> int:
    from bioslam.cli.common import EXIT_INVALID, CommandError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    args.argv = list(sys.argv[1:] if argv is None else argv)
    code, message = 0, None
    try:
        summary = args.func(args)
    except CommandError as exc:
        summary, code, message = exc.summary, exc.code, str(exc)
    except (OSError, ValueError, RuntimeError) as exc:
        interrupt = signals.wrapped_interrupt(exc)
        if interrupt is not None:
            raise interrupt from None
        print(f"bioslam {args.command}: error: {_message(exc)}", file=sys.stderr)
        return EXIT_INVALID
    with signals.protected():
        try:
            if summary is not None:
                print_summary(summary)
        except BrokenPipeError:  # `bioslam run ... | head`: the reader left, the files stay
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        if message:
            print(f"bioslam {args.command}: error: {message}", file=sys.stderr)
    return code


def _message(exc: BaseException) -> str:
    """An OSError's own text names the file as ``[Errno 2] No such file...: 'x'``: say it
    the way the other errors do, ``x: No such file or directory``."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc)


#: BLAS thread pools (OpenBLAS, OpenMP builds) the ``bioslam`` program sizes to one thread
#: unless the environment already says otherwise (:func:`single_threaded_blas`).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas(environ: dict[str, str] | os._Environ[str]) -> None:
    """One BLAS thread unless ``environ`` asks for more. The run's linear algebra is small
    (3x3 solves, a sparse factorisation SuperLU does on one thread) and runs between scans
    on one core; OpenBLAS's default pool of one thread per core makes each call wake the
    others, which then spin waiting for the next one: on the 600 s simulated route 1.6 s of
    CPU (7 % of the scans' own time) on a second core that another job or the reader
    could use, and no faster result. Effective only before NumPy is first imported."""
    for name in BLAS_THREAD_VARIABLES:
        environ.setdefault(name, "1")


def console_main() -> None:
    """The ``bioslam`` program."""
    single_threaded_blas(os.environ)  # before NumPy loads: see its docstring
    from bioslam.memory import map_large_blocks

    map_large_blocks()  # a process of its own: the allocator's settings are ours to choose
    exit_without_teardown(main(exiting=True))


def exit_without_teardown(code: int) -> NoReturn:
    """End the process once the command is done: the exit handlers run and the standard
    streams are flushed, but the interpreter's teardown (freeing every module and object one
    by one, Numba's and LLVM's included) is skipped, as the system frees the memory at once:
    0.37 s of CPU after a run (1.7 % of the 600 s route's per-scan time, a quarter of a short
    log's). Every output is written and closed before the command returns."""
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if run_exit_handlers is None:  # not CPython: the ordinary exit
        sys.exit(code)
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    console_main()

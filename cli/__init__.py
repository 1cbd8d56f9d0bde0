"""The ``markergraph`` command: a thin shell that parses arguments and calls library functions.

Exit codes: 0 done, 1 a problem with the input, the settings, the output or the command line
itself (one line on stderr naming the file, topic, value or flag: every
:class:`MarkerGraphError`, ``OSError``, and argparse's usage errors), 2 a bug of ours, 130
interrupted (Ctrl-C), 143 terminated (SIGTERM).

This module imports nothing heavy: :func:`main` installs its signal handlers first and only then
imports the subcommand named (``map``'s: a second of GTSAM and OpenCV), so that Ctrl-C is one
line at any moment.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from markergraph.cli import _signals

if TYPE_CHECKING:
    import argparse

__all__ = ["main"]

EXIT_OK, EXIT_USER_ERROR, EXIT_INTERNAL_ERROR = 0, 1, 2
EXIT_INTERRUPTED = _signals.exit_code(signal.SIGINT)  # 130


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code.

    Args:
        argv: the arguments; None reads this process's own command line (and then the signal
            handlers stay in place until the process ends).
    """
    with _signals.handled(process=argv is None) as signals:
        from markergraph.cli._parser import parse_command_line  # the heavy imports, handled

        parser, args = parse_command_line(argv)
        if args.command is None:
            parser.print_help()
            return EXIT_OK
        signals.running(args.command)
        return _run(args, signals)


def _run(args: argparse.Namespace, signals: _signals.Signals) -> int:
    """The subcommand, its errors turned into one line and an exit code."""
    from markergraph.common.errors import MarkerGraphError

    try:
        return _dispatch(args)
    except KeyboardInterrupt as stop:  # Ctrl-C, or SIGTERM raised as one (see _signals)
        signum = stop.signum if isinstance(stop, _signals.Stopped) else signal.SIGINT
        return _stopped(args.command, signals.received or signum)
    except BrokenPipeError:  # stdout's reader left (`| head`): end quietly, as a shell tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # flushed at exit
        return _signals.exit_code(signal.SIGPIPE)
    except (MarkerGraphError, OSError) as error:
        if signals.received is not None:  # the signal cut a read or a write short
            return _stopped(args.command, signals.received)
        print(f"markergraph {args.command}: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as error:  # a bug of ours: say so plainly
        if signals.received is not None:  # a signal a C extension turned into another error
            return _stopped(args.command, signals.received)
        if os.environ.get("MARKERGRAPH_DEBUG"):
            raise
        print(
            f"markergraph {args.command}: internal error: {error!r} "
            "(set MARKERGRAPH_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL_ERROR


def _stopped(command: str, signum: int) -> int:
    """The one line of a run a signal stopped, and its exit code (130 or 143)."""
    print(_signals.stopped_line(command, signum), file=sys.stderr)
    return _signals.exit_code(signum)


def _dispatch(args: argparse.Namespace) -> int:
    """The subcommand ``args`` name, run."""
    from markergraph.cli._commands import command

    return command(args.command).runner()(args)

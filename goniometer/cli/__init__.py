"""The ``gonio`` command line host: it parses, dispatches, and prints user errors as one line.

The simulator's own commands (``simulate``, ``info``, ``database``, ``tabulate``, ``export``) live beside this module.
Every other command is a plugin: an entry point of the group ``goniometer.commands`` (declared
in ``pyproject.toml``) names a function ``register(subparsers)`` that adds its sub-commands.
The host never imports a plugin's package, so the simulator stands without the models
(``docs/architecture.md``). Plugins keep ``register`` light (imports inside the commands), so
``gonio --help`` imports no model.

Every user error prints one line ``gonio: error: ...`` on stderr and exits with status 2 (a value
the parser refuses: ``gonio CMD: error: --option: ...; see gonio CMD --help``, :class:`Parser`);
an interrupted run (Ctrl-C) exits with 130 and leaves no file under the output name. A failure of
the environment -- a full disk, a quota, a read-only file system: an OSError of
:data:`goniometer.atomic.ENVIRONMENT_ERRNOS` that names its file -- prints one line
``gonio: error: cannot write PATH: No space left on device`` (with what the command kept, if it
says) and exits with status 1; any other OSError is a bug and keeps its traceback. Output cut
short by its reader (``gonio database list ... | head``) ends quietly with status 141
(128 + SIGPIPE, what a shell tool killed by the broken pipe reports). ``docs/outputs.md`` lists
the exit statuses.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
from importlib.metadata import entry_points
from typing import Callable, NoReturn, Sequence

from goniometer.cli import database, simulate, tabulate
import goniometer
from goniometer.atomic import WriteError, is_environment_error
from goniometer.cli.common import EXIT_INTERRUPTED, EXIT_USAGE, UsageError

#: exit status when stdout's reader went away (128 + SIGPIPE)
EXIT_BROKEN_PIPE = 141
#: exit status of a failure of the environment (disk full, quota, read-only file system: docs/outputs.md)
EXIT_ENVIRONMENT = 1

__all__ = ["ENTRY_POINT_GROUP", "EXIT_ENVIRONMENT", "EXIT_INTERRUPTED", "EXIT_USAGE", "Parser", "UsageError",
           "build_parser", "main"]

#: the entry-point group through which packages contribute ``gonio`` sub-commands
ENTRY_POINT_GROUP = "goniometer.commands"


def plugins() -> list[Callable[[argparse._SubParsersAction], None]]:
    """The ``register`` functions of the installed command plugins, in entry-point name order."""
    found = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: ep.name)
    return [ep.load() for ep in found]


class Parser(argparse.ArgumentParser):
    """The parser of ``gonio`` and of every sub-command, the plugins' included (``add_subparsers``
    makes its parsers of the parent's class): a value it refuses is one line on stderr, exit 2,

        gonio simulate: error: --rays: 'abc' is not a whole number (e.g. 100000 or 1e5); see gonio simulate --help

    not argparse's usage block above the line that matters."""

    def error(self, message: str, prog: str | None = None) -> NoReturn:
        prog = prog or self.prog
        if message.startswith("argument "):   # "argument --rays: ..." -> "--rays: ...", as every other error names it
            message = message[len("argument "):]
        self.exit(EXIT_USAGE, f"{prog}: error: {message}; see {prog} --help\n")

    def parse_known_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
                         ) -> tuple[argparse.Namespace, list[str]]:
        ns, extras = super().parse_known_args(args, namespace)
        if extras and not hasattr(ns, _UNRECOGNIZED_BY):   # the innermost sub-command returns first
            setattr(ns, _UNRECOGNIZED_BY, self.prog)
        return ns, extras

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        ns, extras = self.parse_known_args(args, namespace)
        if extras:   # named by the sub-command that was given them: gonio simulate: error: unrecognized ...
            self.error(f"unrecognized arguments: {' '.join(extras)}", prog=getattr(ns, _UNRECOGNIZED_BY, None))
        return ns


#: the namespace attribute through which :class:`Parser` learns which sub-command left arguments over
_UNRECOGNIZED_BY = "_gonio_unrecognized_by"


def build_parser() -> argparse.ArgumentParser:
    """The ``gonio`` parser: the simulator's commands, then every plugin's."""
    parser = Parser(prog="gonio", description="Monte Carlo virtual goniometer for layered materials.")
    parser.add_argument("--version", action="version", version=f"gonio (goniometer) {goniometer.__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    simulate.register(sub)
    database.register(sub)
    tabulate.register(sub)
    for register in plugins():
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``gonio`` with ``argv`` (default: the process's arguments); returns the exit status."""
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
        func: Callable[[argparse.Namespace], int] = args.func
        code = func(args)
        sys.stdout.flush()  # here, so that a broken pipe is caught below and not at exit
        return code
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except UsageError as e:
        print(f"gonio: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        out = getattr(args, "out", None)
        note = f"; nothing written to {out}" if out else ""
        print(f"gonio: interrupted{note}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as e:
        if not is_environment_error(e):
            raise   # a bug: its traceback
        print(f"gonio: error: {environment_error(e)}", file=sys.stderr)
        return EXIT_ENVIRONMENT


#: the errors that mean a write failed whatever was being done when they came
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


def environment_error(e: OSError) -> str:
    """The line of an OSError of the environment: ``cannot write PATH: No space left on device``
    (``cannot access PATH: ...`` for an error that need not be a write's), then the notes the
    command added (what it kept, how to go on), on one line."""
    verb = "cannot write" if isinstance(e, WriteError) or e.errno in _WRITE_ERRNOS else "cannot access"
    line = f"{verb} {e.filename}: {os.strerror(e.errno)}"
    notes = [n for n in getattr(e, "__notes__", ()) if isinstance(n, str)]
    return "; ".join([line, *notes]).replace("\n", " ")


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that Python's final flush of what is left in its buffer
    does not fail again on the closed pipe (and print "Exception ignored ...")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # stdout without a file descriptor (captured in tests)
        pass

"""The error boundary of every command.

    def main(argv=None) -> int: ...
    if __name__ == "__main__":
        run_cli(main)

Bad input (`InputError`) prints one line and exits 2; an environment error (disk full, read-only
file system, permission, no CUDA) prints one line naming the path and exits 1; a command that ran
and found problems (frames it could not fuse, a failed check, parts that do not merge) prints one
line per problem and returns EXIT_PROBLEMS (1); Ctrl-C exits 130 (docs/errors.md).
`--debug` anywhere on the command line (or FISHEYE_BEV_DEBUG=1) shows the full traceback instead.
"""

from __future__ import annotations

import argparse
import os
import sys

from .errors import InputError, MachineError

EXIT_BAD_INPUT = 2
EXIT_ENVIRONMENT = 1
EXIT_PROBLEMS = 1
EXIT_INTERRUPTED = 130


def print_problems(problems) -> int:
    """Print each problem (one line each) on stderr; EXIT_PROBLEMS when there are any, else 0."""
    for p in problems:
        print(p, file=sys.stderr)
    return EXIT_PROBLEMS if problems else 0


def require_positive(option: str, n: int | None) -> None:
    """A count option (--workers, --threads), when given, is at least 1: one line, exit 2, otherwise."""
    if n is not None and n < 1:
        raise InputError(f"{option}: must be >= 1, got {n}")


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error (InputError, exit 2) instead of the usage block."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message} (see --help)")


def _environment_message(exc: OSError) -> str:
    where = exc.filename if exc.filename is not None else ""
    what = exc.strerror or str(exc) or type(exc).__name__
    return f"{where}: {what}" if where else what


def run_cli(main, argv=None, prog: str | None = None) -> None:
    """Run `main(argv) -> int` and exit with its code, turning errors into one line."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("FISHEYE_BEV_DEBUG") == "1"
    argv = [a for a in argv if a != "--debug"]
    prog = prog or os.path.basename(sys.argv[0])
    if debug:
        sys.exit(main(argv))
    try:
        code = main(argv)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = EXIT_BAD_INPUT
    except MachineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = EXIT_ENVIRONMENT
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; run the same command again to resume", file=sys.stderr)
        code = EXIT_INTERRUPTED
    except MemoryError:
        print("error: out of memory", file=sys.stderr)
        code = EXIT_ENVIRONMENT
    except OSError as exc:
        print(f"error: {_environment_message(exc)}", file=sys.stderr)
        code = EXIT_ENVIRONMENT
    except RuntimeError as exc:  # torch's "no CUDA" and the like: the environment, not the input
        print(f"error: {str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__} (run with --debug for the trace)", file=sys.stderr)
        code = EXIT_ENVIRONMENT
    sys.stdout.flush()
    sys.exit(code)

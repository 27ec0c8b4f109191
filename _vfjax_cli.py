"""The ``vfjax`` command's entry point, kept apart from the package so that it runs first.

``import vfjax`` loads JAX, SciPy and the rest, which takes seconds on a fresh process. A
Ctrl-C pressed then, before `vfjax.cli.main` has installed its interrupt handler, would end
the command with Python's traceback; here it ends like any other interrupt of the command
line: one line on stderr and exit code 130. (``python -m vfjax`` imports the package before
any of its code runs, so only the installed ``vfjax`` command has this guard.)
"""

import os
import sys

#: The command line's line on an interrupt (`vfjax.cli` prints the same).
INTERRUPTED = "vfjax: interrupted; the output folder is left as it was"


def main() -> int:
    """Import the command line and run it; a Ctrl-C before its handler is in place ends the
    process with `INTERRUPTED` and exit code 130 (nothing has been written yet)."""
    try:
        from vfjax.cli import main as command_line

        return command_line()
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)  # no interpreter teardown under threads a half-done import started


if __name__ == "__main__":
    raise SystemExit(main())

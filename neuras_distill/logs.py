"""The package's messages: one logger, ``logging.getLogger("neuras_distill")``, and the handler the command line
installs (this module owns the logging setup).

Every module speaks through :data:`LOGGER` (or a child, ``neuras_distill.<room>``): INFO for what a user follows
(stages, decisions, what was reused, geometry's phases), DEBUG for detail, WARNING for what needs attention. The
library installs no handler but a ``NullHandler``: an application decides where messages go (Python's own
last-resort handler still shows warnings). ``neuras-distill`` installs :func:`install_cli_handler`: one line a
message on stderr, written so that the run's progress bar (``pipeline/progress.py``) stays below them; ``-v``
shows DEBUG with the logger's name, ``--quiet`` only warnings and errors.
"""

from __future__ import annotations

import logging

LOGGER = logging.getLogger("neuras_distill")
LOGGER.addHandler(logging.NullHandler())

#: ``-v`` / default / ``--quiet`` as logging levels.
LEVELS = {"verbose": logging.DEBUG, "normal": logging.INFO, "quiet": logging.WARNING}


def logger(room: str) -> logging.Logger:
    """The child logger ``neuras_distill.<room>`` (e.g. ``logger("geometry")``)."""
    return LOGGER.getChild(room)


def say(message: str) -> None:
    """One line to the user at INFO: the default ``log`` of ``distill`` and of the commands."""
    LOGGER.info(message)


class _BarAwareHandler(logging.StreamHandler):
    """Writes each message through ``tqdm.write``, which clears and redraws an active progress bar around it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm.auto import tqdm

            tqdm.write(self.format(record), file=self.stream)
            self.flush()
        except Exception:  # noqa: BLE001 (logging's contract: a failing handler reports, never raises)
            self.handleError(record)


def install_cli_handler(level: str = "normal") -> logging.Handler:
    """The command line's handler on stderr at ``level`` (a key of :data:`LEVELS`), replacing an earlier one;
    returns it. The logger does not propagate to the root logger, so nothing prints twice."""
    import sys

    for old in [h for h in LOGGER.handlers if isinstance(h, _BarAwareHandler)]:
        LOGGER.removeHandler(old)
    handler = _BarAwareHandler(sys.stderr)
    verbose = level == "verbose"
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s" if verbose else "%(message)s"))
    LOGGER.addHandler(handler)
    LOGGER.setLevel(LEVELS[level])
    LOGGER.propagate = False
    return handler

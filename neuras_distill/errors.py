"""The one exception type users see for bad input.

Library code raises :class:`BadInputError` (never ``assert`` or ``sys.exit``) for anything the user can fix:
a malformed camera file, a field with no surface, an impossible budget. The CLI turns it into exit code 2 and
one line on stderr; anything else is an internal error (exit code 1).
"""

from __future__ import annotations


class BadInputError(ValueError):
    """A problem with what the user gave us. The message says what is wrong and what to do about it."""


class AtlasTooSmallError(BadInputError):
    """A fixed atlas side below what the mesh's UV charts need; ``need``: the smallest side (texels) that fits them."""

    def __init__(self, message: str, need: int):
        super().__init__(message)
        self.need = int(need)


def require(condition: bool, message: str) -> None:
    """Raise :class:`BadInputError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise BadInputError(message)

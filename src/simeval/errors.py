"""The one exception type for mistakes a user can fix (a bad path, value or file).

Entry points turn a `UserError` into one line on stderr and exit status 2, with no traceback (set
`HYDRA_FULL_ERROR=1` to see it). Library code raises it where it knows the file, key or value at fault; the
message names that thing and what would be valid, e.g.::

    raise UserError(f"{path}: row 7, column 'Human': 'abc' is not a number")
"""

from __future__ import annotations


class UserError(ValueError):
    """A fixable input mistake. Subclasses ValueError so callers that catch ValueError keep working."""


def require_whole(key: str, value: object, low: int = 1) -> None:
    """Raise a UserError naming `key` unless value is an int (not a bool) >= low: configs give strings and floats
    as readily as ints, and a comparison with them fails far from the key that caused it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UserError(f"{key} must be a whole number >= {low}, got {value!r}")

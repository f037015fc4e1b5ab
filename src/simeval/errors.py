"""The one exception type for mistakes a user can fix (a bad path, value or file).

Entry points turn a `UserError` into one line on stderr and exit status 2, with no traceback (set
`HYDRA_FULL_ERROR=1` to see it). Library code raises it where it knows the file, key or value at fault; the
message names that thing and what would be valid, e.g.::

    raise UserError(f"{path}: row 7, column 'Human': 'abc' is not a number")
"""

from __future__ import annotations


class UserError(ValueError):
    """A fixable input mistake. Subclasses ValueError so callers that catch ValueError keep working."""

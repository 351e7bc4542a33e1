"""The one exception type for input that was checked and refused."""

from __future__ import annotations


class InputError(ValueError):
    """Input that was checked and refused (a bad argument, file, folder or setting); its
    message says what was wrong and what to do. The command line prints it as one line and
    exits with code 2. Any other exception is a bug and shows its traceback (exit 1)."""


SEED_LIMIT = 2**63
"""seeds are integers in [0, SEED_LIMIT): numpy's generators take no negative seed, and torch's
no larger one"""


def check_seed(seed: object, flag: str = "--seed") -> int:
    """``seed`` if it is a usable seed, else an InputError naming ``flag``."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < SEED_LIMIT:
        raise InputError(f"{flag} must be an integer in [0, 2**63), got {seed!r}")
    return seed

"""The one exception type for input that was checked and refused."""

from __future__ import annotations


class InputError(ValueError):
    """Input that was checked and refused (a bad argument, file, folder or setting); its
    message says what was wrong and what to do. The command line prints it as one line and
    exits with code 2. Any other exception is a bug and shows its traceback (exit 1)."""

"""Errors that a user can act on: the CLI prints their message (no traceback) and exits 2."""


class SignSplatError(Exception):
    """Base of user-facing errors: the message names the file, key or value at fault."""


class InputError(SignSplatError, ValueError):
    """An input file is missing, unreadable or malformed (the message names the file)."""

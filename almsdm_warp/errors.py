"""Errors that the command line turns into one line and exit code 2."""


class InputError(ValueError):
    """Bad input: a broken or unreadable mesh, an impossible parameter, an unwritable path.

    The message says where (file, element) and what (the value), in one line.
    """

"""Errors a person caused (a bad file, a bad argument): the CLI prints them on one line, exit code 2."""


class InputError(Exception):
    """An invalid file or argument. The message is one line that names the file and the field."""

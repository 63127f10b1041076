"""Errors that carry a one-line message for the user."""


class InputError(ValueError):
    """Invalid user input (a file, a CLI number, a template set).

    The message is one line that names the field and the rule it breaks; the CLI prints
    it and exits with status 2.
    """

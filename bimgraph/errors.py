"""Errors a user can fix, each with its exit code.

The CLI turns these into one line on stderr and a non-zero exit; anything else is a bug and
keeps its traceback.
"""


class BimgraphError(Exception):
    """Base of every error that is the input's fault, not the program's."""

    exit_code = 1


class InputError(BimgraphError):
    """A file is missing, unreadable, or not what it claims to be."""

    exit_code = 2


class FormatError(InputError):
    """A file parses but breaks its documented schema. The message names the line and field."""

    exit_code = 3


class ConfigError(BimgraphError):
    """The configuration or a command-line option is invalid."""

    exit_code = 4


class SingularError(BimgraphError):
    """The graph's linear system became singular: some variable is left unconstrained, or the
    input's covariances are far overconfident."""

    exit_code = 5

"""The error ``agrinerf-count`` reports for input it cannot use (the command prints it and exits with status 2)."""


class CountInputError(ValueError):
    """Input the counting cannot use (a run without depth, an empty render folder, a scene without truth fruit, an
    output the run does not have); the message names the file or the output."""

"""Tri-modal (RGB + thermal + event) dataparser, installed as ``agrinerf_ns.dataparsers``.

Importing this package activates the compatibility shims (offline LPIPS, checkpoint loading on torch >= 2.6) and the
one-line report of a user's dataset error (:mod:`.user_errors`): every ``ns-*`` command imports the plugin's
dataparser entry point before it runs.
"""

import os
import warnings

from agrinerf_ns import compat


def install_user_errors() -> None:
    """A user's dataset error: one message, no traceback, no run folder (:mod:`.user_errors`). Safe to call more
    than once (the method configs call it again once Nerfstudio's ``ExperimentConfig`` exists); never raises."""
    if os.environ.get("AGRINERF_NO_COMPAT") == "1":
        return
    try:
        from agrinerf_ns.dataparsers import user_errors

        user_errors.install()
    except Exception as err:  # a plugin must never break `ns-*` commands
        warnings.warn(f"agrinerf-ns: installing the user-error report failed: {err!r}", RuntimeWarning, stacklevel=2)


compat.activate()
install_user_errors()

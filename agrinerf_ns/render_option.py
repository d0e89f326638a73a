"""``ns-render --display-ev EV``: the exposure of the ``rgb_display`` output (:mod:`agrinerf_ns.model.display`).

Nerfstudio's ``ns-render`` has no option for a plugin's outputs, so the plugin takes this one off the command line
when it is first imported (``agrinerf_ns/__init__.py``; Nerfstudio imports the plugin's entry points before it parses
its arguments) and hands the value on in the environment variable :data:`EV_ENV`, which a user may also set.
Standard library only: the plugin's first import can happen inside ``import torch``.
"""

from __future__ import annotations

import os
import sys
from typing import List, Optional

EV_ENV = "AGRINERF_DISPLAY_EV"
"""Environment variable that sets the display exposure in stops (what ``ns-render --display-ev`` sets)."""

RENDER_OPTION = "--display-ev"
"""The option this plugin adds to ``ns-render``: the exposure of ``rgb_display`` in stops."""


def env_ev() -> Optional[float]:
    """The exposure set by :data:`EV_ENV`, or None; a clear error for a value that is not a number."""
    text = os.environ.get(EV_ENV)
    if text is None or not text.strip():
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{EV_ENV}={text!r}: the display exposure must be a number of stops, e.g. 2.5") from None


def take_render_option(argv: Optional[List[str]] = None) -> Optional[float]:
    """In ``ns-render``: remove ``--display-ev EV`` (or ``--display-ev=EV``) from the command line before Nerfstudio
    parses it and set :data:`EV_ENV`; returns the value (None where not given). A missing or non-numeric value
    exits with status 2 and names the option."""
    args = sys.argv if argv is None else argv
    if not args or os.path.basename(args[0]) != "ns-render":
        return None
    for index, arg in enumerate(args):
        if arg == RENDER_OPTION or arg.startswith(RENDER_OPTION + "="):
            value = arg.split("=", 1)[1] if "=" in arg else (args[index + 1] if index + 1 < len(args) else "")
            del args[index : index + (1 if "=" in arg else 2)]
            try:
                ev = float(value)
            except ValueError:
                sys.stderr.write(
                    f"ns-render: error: {RENDER_OPTION} needs a number of stops (e.g. 2.5), got {value!r}\n"
                )
                raise SystemExit(2) from None
            os.environ[EV_ENV] = repr(ev)
            return ev
    return None

"""Tri-modal (RGB + thermal + event) dataparser, installed as ``agrinerf_ns.dataparsers``.

Importing this package activates the compatibility shims (offline LPIPS, checkpoint loading on torch >= 2.6): every
``ns-*`` command imports the plugin's dataparser entry point before it runs.
"""

from agrinerf_ns import compat

compat.activate()

"""AgriNeRF method specifications (`ns-train agrinerf`, `ns-train agrinerf-lite`), installed as
``agrinerf_ns.method_configs``. Importing this package activates the compatibility shims (offline LPIPS, checkpoint
loading on torch >= 2.6), because every ``ns-*`` command imports the plugin's entry points first."""

from agrinerf_ns import compat

compat.activate()

"""AgriNeRF method specifications (`ns-train agrinerf`, `ns-train agrinerf-lite`), installed as
``agrinerf_ns.method_configs``. Importing this package activates the compatibility shims (offline LPIPS, checkpoint
loading on torch >= 2.6) and the one-line report of a user's dataset error, because every ``ns-*`` command imports the plugin's entry points first."""

from agrinerf_ns import compat
from agrinerf_ns.dataparsers import install_user_errors

compat.activate()
install_user_errors()  # again: Nerfstudio's ExperimentConfig exists by the time ns-train loads the method configs

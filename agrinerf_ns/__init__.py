"""AgriNeRF for Nerfstudio: RGB + event + thermal radiance fields of farms and orchards."""

from pathlib import Path as _Path

from agrinerf_ns.quiet_warnings import quiet_console_command as _quiet
from agrinerf_ns.render_option import take_render_option as _take_render_option

# The console of an ns-* or agrinerf-* command shows no third-party deprecation warnings (agrinerf_ns.quiet_warnings):
# set here, before the command's modules import torch and Nerfstudio. A no-op in any other program (pytest included).
_quiet()
# ns-render's --display-ev, taken off its command line before Nerfstudio parses it (agrinerf_ns.render_option)
_take_render_option()

__version__ = "0.1.0"

# Imported from a checkout (the checkout root on sys.path: a Ray worker started beside the driver, `python -c` in the
# root) rather than from the install: the subpackages that pyproject.toml maps from other folders are not inside this
# folder, so map them here. An installed package has them inside and skips this.
if (
    not (_Path(__file__).parent / "dataparsers").is_dir()
    and (_Path(__file__).parent.parent / "pyproject.toml").is_file()
):
    from agrinerf_ns.source_tree import map_checkout_subpackages as _map

    _map(_Path(__file__).parent.parent)

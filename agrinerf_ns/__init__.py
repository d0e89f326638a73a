"""AgriNeRF for Nerfstudio: RGB + event + thermal radiance fields of farms and orchards."""

__version__ = "0.1.0"

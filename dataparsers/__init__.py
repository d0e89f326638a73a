"""Tri-modal (RGB + thermal + event) dataparser, installed as ``agrinerf_ns.dataparsers``."""

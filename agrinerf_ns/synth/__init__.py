"""Synthetic tri-modal (RGB + thermal + event) orchard and garden captures with ground truth: ``agrinerf-synth``.

Library use::

    from agrinerf_ns.synth import SynthConfig, generate_capture
    generate_capture(SynthConfig.tiny(seed=3, lighting="dark"), tmp_path / "raw")
"""

from agrinerf_ns.synth.capture import generate_capture
from agrinerf_ns.synth.config import SynthConfig, SynthConfigError

__all__ = ["SynthConfig", "SynthConfigError", "generate_capture"]

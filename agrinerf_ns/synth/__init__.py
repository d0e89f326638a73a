"""agrinerf_ns.synth."""

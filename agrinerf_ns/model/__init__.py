"""agrinerf_ns.model."""

"""agrinerf_ns.process."""

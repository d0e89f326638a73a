"""agrinerf_ns.bench."""

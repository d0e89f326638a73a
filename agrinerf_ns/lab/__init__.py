"""agrinerf_ns.lab."""

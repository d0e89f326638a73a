"""agrinerf_ns.process: raw captures (RGB, raw thermal, events, calibration) -> tri-modal Nerfstudio dataset."""

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.pipeline import ProcessConfig, process_capture

__all__ = ["ProcessConfig", "RawInputError", "process_capture"]

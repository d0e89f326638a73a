"""agrinerf_ns.process: raw captures (RGB, raw thermal, events, calibration) -> tri-modal Nerfstudio dataset."""

from agrinerf_ns.process.pipeline import ProcessConfig, process_capture
from agrinerf_ns.process.readers import RawInputError

__all__ = ["ProcessConfig", "RawInputError", "process_capture"]

"""agrinerf_ns.process: raw captures (RGB, raw thermal, events, calibration) -> tri-modal Nerfstudio dataset."""

from agrinerf_ns.process.capture_to_dataset import ProcessConfig, process_capture
from agrinerf_ns.process.errors import RawInputError

__all__ = ["ProcessConfig", "RawInputError", "process_capture"]

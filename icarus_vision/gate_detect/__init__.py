"""Gate-corner detection: the detector interface, the oracle, and the registry of image detectors."""

from icarus_vision.gate_detect.base import Detector, GateDetection, OracleDetector, validate_image
from icarus_vision.gate_detect.registry import (
    available_detectors,
    make_detector,
    parse_spec,
    register_detector,
)

__all__ = [
    "Detector",
    "GateDetection",
    "OracleDetector",
    "available_detectors",
    "make_detector",
    "parse_spec",
    "register_detector",
    "validate_image",
]

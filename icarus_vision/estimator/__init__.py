"""Relative gate pose estimation: PnP per detection, a Kalman filter per gate, simulated odometry."""

from icarus_vision.estimator.config import (
    EstimatorConfig,
    FilterConfig,
    MeasurementConfig,
    OdometryConfig,
)
from icarus_vision.estimator.estimate import GateEstimate, fill_observation
from icarus_vision.estimator.estimator import GateEstimator
from icarus_vision.estimator.odometry import OdometryReading, SimulatedOdometry, check_odometry
from icarus_vision.estimator.prior import displaced_map

__all__ = [
    "EstimatorConfig",
    "FilterConfig",
    "GateEstimate",
    "GateEstimator",
    "MeasurementConfig",
    "OdometryConfig",
    "OdometryReading",
    "SimulatedOdometry",
    "check_odometry",
    "displaced_map",
    "fill_observation",
]

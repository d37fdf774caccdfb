"""The race report of ARCHITECTURE.md: every field present, ``None`` (JSON null) where it does not apply."""

from __future__ import annotations

REPORT_FIELDS = (
    "track", "laps", "seed", "quad", "detector", "policy", "backend",
    "finished", "crashed", "crash_reason", "gates_total", "gates_passed",
    "lap_times_s", "total_time_s", "max_speed_mps", "mean_speed_mps",
    "sim_time_s", "wall_time_s", "realtime_factor", "perception",
    "time_optimal_s", "time_optimal_ratio",
)  # fmt: skip
PERCEPTION_FIELDS = ("frames", "detection_rate", "rel_gate_error_m")


def empty_perception() -> dict:
    """Perception block for races flown without a camera (all figures null)."""
    return {
        "frames": None,
        "detection_rate": None,
        "rel_gate_error_m": {"median": None, "p95": None},
    }


def validate_report(report: dict) -> None:
    """Raise ValueError when a field of the schema is missing or an unexpected one is present."""
    missing = [f for f in REPORT_FIELDS if f not in report]
    extra = [f for f in report if f not in REPORT_FIELDS]
    if missing or extra:
        raise ValueError(f"race report: missing fields {missing}, unexpected fields {extra}")
    perception = report["perception"]
    if not isinstance(perception, dict) or any(f not in perception for f in PERCEPTION_FIELDS):
        raise ValueError(f"race report: perception must have {PERCEPTION_FIELDS}")

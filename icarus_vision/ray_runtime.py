"""Ray for the commands that scale out (``sweep``, ``gen-dataset --ray``), started once per process."""

from __future__ import annotations

import os


def start_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Join the Ray cluster at ``address``, or start Ray on this machine (None; ``num_cpus``: its
    cores by default). A Ray already running in this process is used as it is. Ray Tune's own
    progress tables are switched off: the commands show their own."""
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    import ray

    if not ray.is_initialized():
        ray.init(address=address, num_cpus=num_cpus, include_dashboard=False,
                 logging_level="ERROR", log_to_driver=False)  # fmt: skip

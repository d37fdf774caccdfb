"""``icarus-vision sweep``: train-policy hyperparameter sweeps on Ray Tune with Optuna's TPE and ASHA."""

from icarus_vision.policy.sweep.run import SweepState, run_sweep
from icarus_vision.policy.sweep.space import SearchSpace, load_space

__all__ = ["SearchSpace", "SweepState", "load_space", "run_sweep"]

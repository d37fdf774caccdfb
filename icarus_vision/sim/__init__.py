"""Simulation core: tracks, quadrotor dynamics, race rules, and the DroneRacingEnv backends."""

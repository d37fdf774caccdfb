"""Closed-loop races: runner, report, plots."""

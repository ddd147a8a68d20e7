"""Simulated surveys with known truth: shapes, scatterers, trajectories, the bistatic simulator."""

"""Solvers: one step of the region's free vertices, state_in -> state_out under a Control."""

from .solver import SolverALMSDM

__all__ = ["SolverALMSDM"]

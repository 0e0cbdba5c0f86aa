"""Protocols: a palpation (press, hold, release, settle), the adaptive region, several probes."""

from .palpation import Palpation, PressResult, SimulationDiverged

__all__ = ["Palpation", "PressResult", "SimulationDiverged"]

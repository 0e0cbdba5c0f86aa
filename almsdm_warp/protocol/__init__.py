"""Protocols: a palpation (press, hold, release, settle), the adaptive region, several probes.

The press schedule (protocol.schedule) is plain Python that the scene files use; the palpation
classes load Warp and the model, so they are imported when first asked for.
"""

__all__ = ["Palpation", "PressResult", "SimulationDiverged"]


def __getattr__(name):
    if name in __all__:
        from . import palpation

        return getattr(palpation, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

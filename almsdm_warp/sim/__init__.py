"""The model on the device: Model (static), State (per step), Control (the probe); surface normals."""

from .model import Control, Model, State

__all__ = ["Control", "Model", "State"]

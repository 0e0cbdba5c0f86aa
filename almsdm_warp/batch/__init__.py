"""Many palpations at once on the device (BatchPalpation) and sweeps built on them."""

from .batch_palpation import BatchPalpation, BatchResult

__all__ = ["BatchPalpation", "BatchResult"]

"""Evaluation and benchmarks: imports the product, never imported by it."""

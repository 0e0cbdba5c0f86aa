"""Export: atomic writes, USD stages, pictures."""

"""Scenes: an organ mesh with its tissue, region and press parameters, from a TOML file."""

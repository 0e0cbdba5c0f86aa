"""The `almsdm` command line."""

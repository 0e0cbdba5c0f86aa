"""Warp kernels of almsdm_warp, each beside the thin launcher that runs it.

Installed as ``almsdm_warp.kernels``; one file per family, so that Warp recompiles little.
"""

"""Tissue: the material parameters (params) and lesions (regions of stiffer tissue)."""

"""Tissue: the material parameters and lesions (regions of stiffer tissue)."""

"""Backward Euler: the row assembly's right-hand side and update, block-Jacobi CG, and its kernels for one
region and a batch."""

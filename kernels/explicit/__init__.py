"""Semi-implicit Euler: the update `advance` and its kernels for one region (and a stroke), a batch, and
the fast batch layout on CUDA."""

"""Kernels that touch the probe: the press (schedule, driven vertex, force record, the frame's hold), the
sphere's contact, several probes, a stroke's spheres."""

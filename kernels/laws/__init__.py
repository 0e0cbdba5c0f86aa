"""Tissue laws, one file each: the `wp.func`s a step kernel composes (kernels/laws/springs.py says which).

A kernel factory (kernels/explicit, kernels/implicit) takes a law from LAWS and builds its kernels
from the law's functions; the host's entry for the law (almsdm_warp/tissue/laws.py) adds its
critical step and its stiffness bound.
"""

import functools

import warp as wp

from . import corotational, neo_hookean, springs

LAWS = {"springs": springs, "neo-hookean": neo_hookean, "corotational": corotational}
"""Law name -> its module of kernel functions (vertex_force; implicit_row and static_row where the law
has them) and the types of its entries (ENTRY_TOPOLOGY, ENTRY_PARAMS, and the struct of the three,
Entries: what a step kernel takes)."""


@functools.cache
def pressure_pass(law: str):
    """A wp.func (region_vertex, count, entries, q) that fills entries.pressure with law `law`'s nodal
    pressures at positions q for the first `count` vertices of region_vertex (one thread, in order);
    nothing for a law without volume. For the one-thread kernels that read a law's forces (a stroke's
    reactions, the ring-motion check)."""
    nodal_pressure, Entries, VOLUMETRIC = LAWS[law].nodal_pressure, LAWS[law].Entries, LAWS[law].VOLUMETRIC

    @wp.func
    def region_pressure(region_vertex: wp.array(dtype=wp.int32), count: int, entries: Entries, q: wp.array(dtype=wp.vec3)):
        if wp.static(VOLUMETRIC):
            for i in range(count):
                v = region_vertex[i]
                entries.pressure[v] = nodal_pressure(entries.offsets[v], entries.offsets[v + 1], entries.topology, entries.params, 0, q, q)

    return region_pressure

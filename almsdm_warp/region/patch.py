"""The patch a spherical probe covers: the seeds (ring 0) of its region, one rule for every path."""

from __future__ import annotations

import math

import numpy as np


def sphere_patches(model, vertices, radius: float, depth: float, chunk: int = 1024):
    """Each contact's sphere patch as CSR (offsets [B + 1], sorted vertex ids): the surface vertices a
    sphere of radius R [m] pressed `depth` [m] at the contact may touch: those within sqrt(2 R d) (the
    contact circle's radius on a flat surface) plus the mesh's longest edge of it, facing the probe
    (rest normals within 90 degrees of the contact's), and the contact itself. The rule of every
    path: Palpation's region (ring 0) and the batch's; `chunk` contacts at a time."""
    mesh = model.mesh
    n = mesh.vertex_count
    surface = np.zeros(n, dtype=bool)
    surface[mesh.surface_vertices] = True
    normals = model.vertex_normal_rest
    reach = math.sqrt(2.0 * radius * max(float(depth), 0.0)) + float(mesh.edge_rest_length.max(initial=0.0))
    counts, ids = [], []
    for begin in range(0, len(vertices), chunk):
        v = vertices[begin : begin + chunk]
        near = np.linalg.norm(mesh.vertices[None, :, :] - mesh.vertices[v][:, None, :], axis=2) <= reach
        mask = near & (normals[v] @ normals.T > 0.0) & surface[None, :]
        mask[np.arange(len(v)), v] = True
        rows, cols = np.nonzero(mask)
        counts.append(np.bincount(rows, minlength=len(v)))
        ids.append(cols)
    offsets = np.concatenate([[0], np.cumsum(np.concatenate(counts))])
    return offsets.astype(np.int32), np.concatenate(ids).astype(np.int32)

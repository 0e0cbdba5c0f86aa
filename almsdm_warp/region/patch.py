"""The patch a spherical probe covers: the seeds (ring 0) of its region, one rule for every path."""

from __future__ import annotations

import math

import numpy as np


def sphere_patches(model, vertices, radius: float, depth: float, chunk: int = 4096):
    """Each contact's sphere patch as CSR (offsets [B + 1], sorted vertex ids): the surface vertices a
    sphere of radius R [m] pressed `depth` [m] at the contact may touch: those within sqrt(2 R d) (the
    contact circle's radius on a flat surface) plus the mesh's longest edge of it, facing the probe
    (rest normals within 90 degrees of the contact's), and the contact itself. The rule of every
    path: Palpation's region (ring 0) and the batch's; `chunk` contacts at a time, each patch's
    candidates from the surface's k-d tree (TissueMesh.surface_tree): work that grows with the
    patches, not with the mesh."""
    mesh = model.mesh
    normals = model.vertex_normal_rest
    reach = math.sqrt(2.0 * radius * max(float(depth), 0.0)) + float(mesh.edge_rest_length.max(initial=0.0))
    surface = mesh.surface_vertices.astype(np.int64)
    counts, ids = [], []
    for begin in range(0, len(vertices), chunk):
        v = np.asarray(vertices[begin : begin + chunk], dtype=np.int64)
        row, near = within(mesh, surface, v, reach)
        facing = np.einsum("ij,ij->i", normals[v][row], normals[near]) > 0.0
        # each row's ids sorted, the contact itself added once
        row = np.concatenate([row[facing], np.arange(len(v))])
        near = np.concatenate([near[facing], v])
        order = np.lexsort((near, row))
        row, near = row[order], near[order]
        first = np.concatenate([[True], (row[1:] != row[:-1]) | (near[1:] != near[:-1])])
        counts.append(np.bincount(row[first], minlength=len(v)))
        ids.append(near[first])
    offsets = np.concatenate([[0], np.cumsum(np.concatenate(counts))])
    return offsets.astype(np.int32), np.concatenate(ids).astype(np.int32)


def within(mesh, surface: np.ndarray, v: np.ndarray, reach: float):
    """(row, vertex): each surface vertex within `reach` [m] of vertex v[row] (|difference| <= reach, as
    NumPy's norm gives it), found through the surface's k-d tree with a little to spare."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(mesh.vertices[v]).sparse_distance_matrix(mesh.surface_tree, reach * (1.0 + 1e-9), output_type="ndarray")
    row, near = pairs["i"].astype(np.int64), surface[pairs["j"]]
    keep = np.linalg.norm(mesh.vertices[near] - mesh.vertices[v][row], axis=1) <= reach
    return row[keep], near[keep]

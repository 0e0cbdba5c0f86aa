"""Where a probe touches the organ: closest surface point and nearest surface vertex, on the device."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import warp as wp

from ..mesh.device_mesh import as_device_mesh
from ..mesh.validate import MAX_COORDINATE_M
from ..kernels.region import contact as ck


class Contacts(NamedTuple):
    """Contacts of a batch of probes (host arrays, SI units)."""

    point: np.ndarray
    """Closest surface point [m], shape [B, 3]."""
    face: np.ndarray
    """Surface triangle that holds it, shape [B], int32."""
    vertex: np.ndarray
    """Nearest surface vertex to that point (where the region is seeded), shape [B], int32."""
    distance: np.ndarray
    """Distance from the probe to the surface [m], shape [B]."""


class ContactQuery:
    """Batched contact queries on one device; buffers grow with the batch and are reused."""

    def __init__(self, mesh, device=None):
        self.dmesh = as_device_mesh(mesh, device)
        self.device = self.dmesh.device
        self._capacity = 0

    def _reserve(self, count: int) -> None:
        if count <= self._capacity:
            return
        d = self.device
        self.probe = wp.zeros(count, dtype=wp.vec3, device=d)
        self.contact_point = wp.zeros(count, dtype=wp.vec3, device=d)
        self.contact_face = wp.zeros(count, dtype=wp.int32, device=d)
        self.nearest_vertex = wp.zeros(count, dtype=wp.int32, device=d)
        self._capacity = count

    def launch(self, count: int) -> None:
        """Run the kernels on the first `count` entries of `self.probe` (already on the device)."""
        ck.eval_contacts(
            self.dmesh, self.probe[:count], self.contact_point[:count], self.contact_face[:count], self.nearest_vertex[:count]
        )

    def __call__(self, probes) -> Contacts:
        p = np.asarray(probes, dtype=np.float64)
        single = p.ndim == 1
        p = p.reshape(-1, 3)
        if not np.all(np.isfinite(p)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(p), axis=1))[0])
            raise ValueError(f"probe {bad} has a non-finite position {p[bad].tolist()}")
        far = np.flatnonzero(np.abs(p).max(axis=1, initial=0.0) > MAX_COORDINATE_M)
        if len(far):  # beyond float32's reach of any mesh the simulator holds: no surface is near
            raise ValueError(f"probe {int(far[0])} at {p[far[0]].tolist()} m is more than {MAX_COORDINATE_M:g} m from the "
                             f"origin, beyond any mesh the simulator holds")
        count = len(p)
        self._reserve(max(count, 1))
        self.probe[:count].assign(p.astype(np.float32))
        self.launch(count)
        point = self.contact_point.numpy()[:count].astype(np.float64)
        out = Contacts(
            point=point,
            face=self.contact_face.numpy()[:count].copy(),
            vertex=self.nearest_vertex.numpy()[:count].copy(),
            distance=np.linalg.norm(point - p, axis=1),
        )
        if single:
            return Contacts(out.point[0], out.face[0], out.vertex[0], out.distance[0])
        return out


def find_contacts(mesh, probes, *, device=None) -> Contacts:
    """Closest surface points and nearest surface vertices for probe positions [m], shape [3] or [B, 3]."""
    return ContactQuery(mesh, device)(probes)


def top_vertex(mesh) -> int:
    """The highest surface vertex (largest z; the first of equals): the default contact, a press from above."""
    sv = mesh.surface_vertices
    return int(sv[np.argmax(mesh.vertices[sv, 2])])

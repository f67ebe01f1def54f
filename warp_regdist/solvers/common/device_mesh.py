"""A mesh's operators on a Warp device, in one precision: what the per-element and per-vertex kernels of
both solvers read."""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["DeviceMesh"]


class DeviceMesh:
    """The arrays of :class:`~warp_regdist.Operators` ``ops`` on ``device`` in ``scalar`` (wp.float32 or
    wp.float64), uploaded once.

    Attributes
    ----------
    elements : (m, d + 1) int32
    basis : (m, d + 1) vec3, the hat-function gradients
    volumes : (m,) element volumes a_e;  vertex_volumes : (n,) lumped A_V;  diameters : (m,) longest edges
    vertex_offsets, incident : (n + 1,), (k,) int32, the elements at each vertex (CSR)
    pair_weights : (k,) vec3, a_e times the gradient of the vertex's hat function on each of them (the
        gather form of D = G^T M_F)
    directions : (m, 3, 2) vec3, ``directions`` (the wedges' unit vectors,
        :func:`~warp_regdist.solvers.common.source_triangles.corner_directions`), or (1, 3, 2) zeros without them
    """

    def __init__(self, ops, scalar, device, directions=None):
        V3 = wp.types.vector(3, scalar)
        self.n, self.m = ops.vertex_volumes.size, ops.element_volumes.size
        self.scalar, self.device = scalar, device
        self.elements = wp.array(np.ascontiguousarray(ops.elements, dtype=np.int32), dtype=wp.int32, device=device)
        self.basis = wp.array(ops.basis, dtype=V3, device=device)
        self.volumes = wp.array(ops.element_volumes, dtype=scalar, device=device)
        self.vertex_volumes = wp.array(ops.vertex_volumes, dtype=scalar, device=device)
        self.diameters = wp.array(ops.diameters, dtype=scalar, device=device)
        offsets, incident, local = ops.vertex_elements
        self.vertex_offsets = wp.array(offsets.astype(np.int32), dtype=wp.int32, device=device)
        self.incident = wp.array(incident.astype(np.int32), dtype=wp.int32, device=device)
        if directions is None:
            directions = np.zeros((1, 3, 2, 3))
        self.directions = wp.array(directions, dtype=V3, device=device)
        self.pair_weights = wp.array(ops.element_volumes[incident, None] * ops.basis[incident, local], dtype=V3,
                                     device=device)

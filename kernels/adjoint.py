"""Differentiable per-element terms of the smoothed problem's stationarity (docs/method.md section 10):
the kernels whose reverse pass gives a vector-Jacobian product's derivatives with respect to
the vertex positions.

For element e with corners v_0..v_d, edge matrix E = [v_1 - v_0, ..., v_d - v_0] (3 x d)
and Gram matrix E^T E, the hat-function gradients are the rows of (E^T E)^-1 E^T (corner 0:
minus their sum) and the volume is sqrt(det E^T E) / d!. With per-vertex u (the smoothed
distance) and w (the adjoint), g = G_e u, p = G_e w . g, t = |g|^2, the kernel writes

    load[e]      = -(a_e / (d + 1)) sum_l w[v_l]      (the term of -A_V . w)
    dirichlet[e] = a_e p                               (times alpha: the Dirichlet term of w . grad F)
    barrier[e]   = 2 p / (1 - t)                       (times mu: the barrier's term)
    volume[e]    = a_e

except on a triangle with a wedge at corner s (``corner[e]`` = s, else -1; the source triangles'
bound u_a <= l_sa), where barrier[e] = sum over its other corners a of (w_a - w_s) / (l_sa - u_a + u_s),
l_sa = |x_a - x_s|

so that w . grad_u F(u; x) = sum(load) + alpha sum(dirichlet) + mu sum(barrier), with alpha and mu
functions of A = sum(volume). Shapes: ``x`` (n,) vec3d, ``elements`` (m, d + 1) int32, ``u``,
``w`` (n,) float64, outputs (m,) float64.
"""

import warp as wp


@wp.func
def _triangle(x0: wp.vec3d, x1: wp.vec3d, x2: wp.vec3d):
    """Volume (area) and the gradients of the barycentric coordinates of corners 1, 2 of a triangle."""
    e1 = x1 - x0
    e2 = x2 - x0
    gram = wp.mat22d(wp.dot(e1, e1), wp.dot(e1, e2), wp.dot(e2, e1), wp.dot(e2, e2))
    inv = wp.inverse(gram)
    b1 = inv[0, 0] * e1 + inv[0, 1] * e2
    b2 = inv[1, 0] * e1 + inv[1, 1] * e2
    return wp.sqrt(wp.determinant(gram)) * wp.float64(0.5), b1, b2


@wp.func
def _tetrahedron(x0: wp.vec3d, x1: wp.vec3d, x2: wp.vec3d, x3: wp.vec3d):
    """Volume and the gradients of the barycentric coordinates of corners 1, 2, 3 of a tetrahedron."""
    e1 = x1 - x0
    e2 = x2 - x0
    e3 = x3 - x0
    gram = wp.mat33d(wp.dot(e1, e1), wp.dot(e1, e2), wp.dot(e1, e3),
                     wp.dot(e2, e1), wp.dot(e2, e2), wp.dot(e2, e3),
                     wp.dot(e3, e1), wp.dot(e3, e2), wp.dot(e3, e3))
    inv = wp.inverse(gram)
    b1 = inv[0, 0] * e1 + inv[0, 1] * e2 + inv[0, 2] * e3
    b2 = inv[1, 0] * e1 + inv[1, 1] * e2 + inv[1, 2] * e3
    b3 = inv[2, 0] * e1 + inv[2, 1] * e2 + inv[2, 2] * e3
    return wp.sqrt(wp.determinant(gram)) / wp.float64(6.0), b1, b2, b3


@wp.func
def _store(e: int, a: wp.float64, g: wp.vec3d, gw: wp.vec3d, wsum: wp.float64, corners: wp.float64,
           load: wp.array(dtype=wp.float64), dirichlet: wp.array(dtype=wp.float64),
           volume: wp.array(dtype=wp.float64)):
    """Element e's load, dirichlet and volume from its volume a, G u, G w and the sum of w on its corners."""
    load[e] = -a / corners * wsum
    dirichlet[e] = a * wp.dot(gw, g)
    volume[e] = a


@wp.func
def _ball_term(g: wp.vec3d, gw: wp.vec3d):
    """2 (G w . g) / (1 - |g|^2): the directional derivative along w of -log(1 - |g|^2)."""
    return wp.float64(2.0) * wp.dot(gw, g) / (wp.float64(1.0) - wp.dot(g, g))


@wp.func
def _wedge_term(x: wp.array(dtype=wp.vec3d), u: wp.array(dtype=wp.float64), w: wp.array(dtype=wp.float64),
                s: int, a: int):
    """(w_a - w_s) / (l_sa - u_a + u_s): the directional derivative along w of -log(1 - (u_a - u_s) / l_sa)."""
    return (w[a] - w[s]) / (wp.length(x[a] - x[s]) - u[a] + u[s])


@wp.kernel
def triangle_terms(x: wp.array(dtype=wp.vec3d), elements: wp.array2d(dtype=wp.int32),
                   u: wp.array(dtype=wp.float64), w: wp.array(dtype=wp.float64), corner: wp.array(dtype=wp.int32),
                   load: wp.array(dtype=wp.float64), dirichlet: wp.array(dtype=wp.float64),
                   barrier: wp.array(dtype=wp.float64), volume: wp.array(dtype=wp.float64)):
    """load, dirichlet, barrier and volume of triangle e (module docstring)."""
    e = wp.tid()
    i0 = elements[e, 0]
    i1 = elements[e, 1]
    i2 = elements[e, 2]
    a, b1, b2 = _triangle(x[i0], x[i1], x[i2])
    b0 = -(b1 + b2)
    g = u[i0] * b0 + u[i1] * b1 + u[i2] * b2
    gw = w[i0] * b0 + w[i1] * b1 + w[i2] * b2
    _store(e, a, g, gw, w[i0] + w[i1] + w[i2], wp.float64(3.0), load, dirichlet, volume)
    c = corner[e]
    if c >= 0:   # each array element is written once: the reverse pass adds the adjoint of every store
        s = elements[e, c]
        barrier[e] = (_wedge_term(x, u, w, s, elements[e, (c + 1) % 3])
                      + _wedge_term(x, u, w, s, elements[e, (c + 2) % 3]))
    else:
        barrier[e] = _ball_term(g, gw)


@wp.kernel
def tetrahedron_terms(x: wp.array(dtype=wp.vec3d), elements: wp.array2d(dtype=wp.int32),
                      u: wp.array(dtype=wp.float64), w: wp.array(dtype=wp.float64),
                      load: wp.array(dtype=wp.float64), dirichlet: wp.array(dtype=wp.float64),
                      barrier: wp.array(dtype=wp.float64), volume: wp.array(dtype=wp.float64)):
    """load, dirichlet, barrier and volume of tetrahedron e (module docstring)."""
    e = wp.tid()
    i0 = elements[e, 0]
    i1 = elements[e, 1]
    i2 = elements[e, 2]
    i3 = elements[e, 3]
    a, b1, b2, b3 = _tetrahedron(x[i0], x[i1], x[i2], x[i3])
    b0 = -(b1 + b2 + b3)
    g = u[i0] * b0 + u[i1] * b1 + u[i2] * b2 + u[i3] * b3
    gw = w[i0] * b0 + w[i1] * b1 + w[i2] * b2 + w[i3] * b3
    _store(e, a, g, gw, w[i0] + w[i1] + w[i2] + w[i3], wp.float64(4.0), load, dirichlet, volume)
    barrier[e] = _ball_term(g, gw)

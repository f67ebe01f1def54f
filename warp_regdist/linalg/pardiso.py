"""Sparse Cholesky by MKL PARDISO through ctypes (the ``[pardiso]`` extra: Intel's ``mkl`` wheel).

PARDISO (Schenk and Gaertner) factorizes a symmetric positive definite A = L D L^T with a nested
dissection ordering (METIS) and supernodes on MKL's threads; :class:`PardisoCholesky` holds one
factorization (phase 12, or 22 alone for new values on the analysed pattern; 33 per solve, -1 on
release) of the upper triangle of A in CSR with 1-based indices, PARDISO's default parameters
(iparm[0] = 0).
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
import site
import sys
import weakref

import numpy as np
import scipy.sparse as sp

__all__ = ["PardisoCholesky", "PardisoError", "load_mkl"]

_SPD = 2


class PardisoError(RuntimeError):
    """PARDISO returned a nonzero error code (-4: a zero or negative pivot, A not positive definite)."""


@functools.cache
def load_mkl():
    """MKL's runtime library (ctypes.CDLL), searched where the ``mkl`` wheel puts it (``lib`` under
    sys.prefix or the user base) and on the loader's path; OSError where there is none."""
    names = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*"))
                   + glob.glob(os.path.join(site.USER_BASE, "lib", "libmkl_rt.so*"))
                   + glob.glob(os.path.join(sys.prefix, "Library", "bin", "mkl_rt*.dll")), key=len)
    names += ["libmkl_rt.so.2", "libmkl_rt.so"]
    for name in names:
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        p, i = ctypes.POINTER(ctypes.c_int64), ctypes.POINTER(ctypes.c_int32)
        lib.pardiso.argtypes = [p, i, i, i, i, i, ctypes.c_void_p, i, i, i, i, i, i, ctypes.c_void_p,
                                ctypes.c_void_p, i]
        lib.pardiso.restype = None
        return lib
    raise OSError(f"expected MKL's libmkl_rt (pip install mkl), got none in {sys.prefix}/lib or on the loader's path")


class PardisoCholesky:
    """A = L D L^T of a symmetric positive definite ``A`` (n, n) scipy sparse (both triangles or the
    upper one). ``solve(b)`` for b (n,) float64; ``refactor(A2)`` factors another matrix in its
    place, reusing the ordering and symbolic analysis where A2 has A's pattern (``generation``
    counts the factorizations); ``release()`` frees PARDISO's memory (also on garbage collection
    and at exit). PardisoError where PARDISO fails (A not numerically positive definite)."""

    def __init__(self, A):
        self._lib = load_mkl()
        self.generation = 0
        self._analyse(_upper(A))

    def _analyse(self, upper):
        """A new handle: ordering, symbolic and numerical factorization (phase 12) of ``upper``."""
        self.n = upper.shape[0]
        self._a = np.ascontiguousarray(upper.data, dtype=np.float64)
        self._ia = (upper.indptr + 1).astype(np.int32)
        self._ja = (upper.indices + 1).astype(np.int32)
        self._pt = np.zeros(64, dtype=np.int64)
        self._iparm = np.zeros(64, dtype=np.int32)
        self._release = weakref.finalize(self, _call, self._lib, self._pt, self._iparm, -1, self.n, self._a,
                                         self._ia, self._ja, np.zeros(self.n))
        self._factor(12)

    def _factor(self, phase):
        try:
            self._call(phase, np.zeros(self.n))
        except PardisoError:
            self.release()
            raise

    def _call(self, phase, b):
        return _call(self._lib, self._pt, self._iparm, phase, self.n, self._a, self._ia, self._ja, b)

    def refactor(self, A):
        """Factor ``A`` instead: the numerical phase alone (22) where its upper triangle has the
        analysed pattern, else a new analysis; earlier factorizations are gone."""
        upper = _upper(A)
        self.generation += 1
        if (self._release.alive and upper.shape[0] == self.n and upper.nnz == self._a.size
                and np.array_equal(upper.indptr + 1, self._ia) and np.array_equal(upper.indices + 1, self._ja)):
            self._a[:] = upper.data
            self._factor(22)
        else:
            self.release()
            self._analyse(upper)

    def solve(self, b):
        """x (n,) with A x = b."""
        if not self._release.alive:
            raise RuntimeError("expected a PardisoCholesky not yet released, got a released one")
        return self._call(33, np.ascontiguousarray(b, dtype=np.float64))

    def release(self):
        """Free PARDISO's memory now (it is also freed when the object is collected, or at exit)."""
        self._release()


def _upper(A):
    upper = sp.triu(A, format="csr")
    upper.sort_indices()
    return upper


def _call(lib, pt, iparm, phase, n, a, ia, ja, b):
    """One call of PARDISO on the handle ``pt``: x (n,) of phase 33, zeros of the others."""
    x = np.zeros_like(b)
    error = ctypes.c_int32(0)
    i32 = ctypes.POINTER(ctypes.c_int32)
    one = ctypes.byref(ctypes.c_int32(1))
    lib.pardiso(pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), one, one, ctypes.byref(ctypes.c_int32(_SPD)),
                ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(n)), a.ctypes.data,
                ia.ctypes.data_as(i32), ja.ctypes.data_as(i32), None, one, iparm.ctypes.data_as(i32),
                ctypes.byref(ctypes.c_int32(0)), b.ctypes.data, x.ctypes.data, ctypes.byref(error))
    if error.value != 0:
        raise PardisoError(f"expected PARDISO phase {phase} to succeed, got error {error.value}")
    return x

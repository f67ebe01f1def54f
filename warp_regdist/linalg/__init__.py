"""Linear algebra of the solvers: the batched preconditioned CG in Warp kernels (``pcg``), its smoothed
aggregation multigrid preconditioner (``multigrid``), CSR matrices on the device (``csr``) and MKL PARDISO's
Cholesky for the gradients' Newton systems (``pardiso``)."""

"""The solvers: single sources (``solver``, ``single_source_batch``) and all pairs (``all_pairs_*``),
the ADMM loop and penalty schedule they share (``admm``), their stopping rule (``stopping``),
the PCG and its multigrid preconditioner, and the worker processes and Ctrl-C handling."""

"""The solvers, one folder per concept: ``single_source`` (one ADMM per source set, batched in lanes),
``all_pairs`` (the symmetric matrix ADMM, its two engines, checkpoints and memory model) and ``common``
(the ADMM loop and penalty schedule, the stopping rule, progress, Ctrl-C and worker processes, the
results, the constraint per element). Their linear algebra lives in :mod:`warp_regdist.linalg`."""

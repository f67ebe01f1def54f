"""Single sources: :class:`~warp_regdist.DistanceSolver` (``solver``), one batched ADMM on the device
(``batch``), source sets, points and curves (``sources``) and gradients through a solve (``gradients``)."""

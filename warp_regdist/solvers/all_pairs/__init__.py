"""All pairs: :class:`~warp_regdist.AllPairsSolver` (``solver``), the consensus engine's state and worker
parts (``state``), the eigenbasis engine (``eigenbasis``), what the loop needs of either (``engine``), the
loop with its residuals, change test and checkpoints (``run``, ``checkpoint``), what a run will take
(``forecast``) and the memory model (``memory``)."""

"""All pairs: :class:`~warp_regdist.AllPairsSolver` (``solver``), the consensus engine's state and worker
parts (``state``), the eigenbasis engine (``eigenbasis``), the loop with its residuals, change test and
checkpoints (``run``, ``checkpoint``) and the memory model (``memory``)."""

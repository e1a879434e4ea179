"""Training: losses, steps shared by ``lsr train`` and ``lsr finetune``, checkpoints, the NaN guard."""

"""The commands that run a job end to end (``lsr reenact``, ``lsr demo``) over the inference core and the writer."""

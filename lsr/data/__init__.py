"""Datasets: the on-disk format, the synthetic generator, real-video preparation, episodes."""

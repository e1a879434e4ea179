"""Evaluation: metrics, protocol, baselines and benchmarks."""

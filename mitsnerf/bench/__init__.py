"""Benchmark sweeps: configurations, the runner, tables."""

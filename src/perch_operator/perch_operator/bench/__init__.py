"""Benchmarks: `perch bench mission`, `memory`, `scans` and `soak`."""

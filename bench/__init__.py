"""Benchmarks: ``python -m bench.<name> [--json]`` prints figures (never pass/fail)."""

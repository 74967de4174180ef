"""Reproducible benchmarks; each module prints its figures and writes them under bench/results/."""

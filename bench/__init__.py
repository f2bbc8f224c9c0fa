"""Benchmarks (not tests): speed, accuracy and their chart. Run each from the repository root as a module,
`python -m bench.NAME --help`; results land in bench/results/NAME/ (index: bench/results/README.md)."""

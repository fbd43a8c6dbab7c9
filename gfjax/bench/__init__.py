"""Benchmarks of gfjax's ground filters against each other and the peer packages (SPEC 6, 9).

- `gfjax.bench.harness`: warm-up and repeated wall times, JAX compile time, peak RSS of a run
  in a fresh process; reusable by speed experiments.
- `gfjax.bench.peers`: adapters for `pysmrf` and `cloth-simulation-filter` (optional extra).
- `gfjax.bench.job`: one (file, filter) run: read + filter + write, accuracy against labels.
- `gfjax.bench.run`: all pairs, the table, the JSON document and the plot (`gfjax bench`).
"""
from __future__ import annotations

from gfjax.bench import harness, peers

__all__ = ["harness", "peers"]

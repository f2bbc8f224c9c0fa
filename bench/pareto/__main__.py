"""`python -m bench.pareto`."""
from bench.pareto.cli import main

raise SystemExit(main())

"""Stage 4 of a render: the tiers, one file each (formula, residual, diffusion), named only by `registry`."""

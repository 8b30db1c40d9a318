"""Infrastructure: worker pools, signals, output folders, manifests, run budgets."""

"""Fitting parameters: the estimation engine, measured and synthetic data, randomisation."""

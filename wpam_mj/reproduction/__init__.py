"""Reproducing the paper: its findings, calibration, the global search and the report."""

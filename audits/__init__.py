"""Accuracy audits and stress sweeps: each script reruns points against a tighter or longer
reference and writes a table (``python audits/NAME.py --help``); ``common`` holds what they
share. Speed benchmarks are in ``benchmarks/``."""

"""The nightly regression suite: spec, suite, comparison, report, run."""

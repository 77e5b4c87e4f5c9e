"""The benchmark harness (policies x fields x seeds) and its report."""

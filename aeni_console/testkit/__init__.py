"""Test support: the real engine driven headless for tests, screenshots and benchmarks."""

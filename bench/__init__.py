"""Benchmarks of issue 2: codec throughput beside pymavlink, and command round trip over a real pty."""

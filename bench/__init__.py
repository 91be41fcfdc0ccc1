"""Benchmarks: the codec beside pymavlink, command round trips over a real pty, real time, lock-step speed, tracking."""

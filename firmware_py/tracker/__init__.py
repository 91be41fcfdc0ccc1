"""The solar tracker's controller: the report's control box, its relay logic, its interlocks, a sun-rate feed-forward.

box.py: the box and its interlocks; logic.py: the relay logic and the feed-forward; task.py: the 10 ms task.
Design: docs/tracker.md#the-controller-in-detail
"""

"""Benches as a product: the target a bench talks to (`target.py`) and the pytest plugin (`pytest_plugin.py`)
that gives any project's tests one, and collects teleop scripts as tests (docs/benches.md)."""

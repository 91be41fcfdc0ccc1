"""What a bench may ask of a target that it cannot give (kept apart: the pytest plugin loads it at start-up)."""


class CannotFault(Exception):
    """This target has no plant to fault or read (real hardware, or a live simulator without a control endpoint)."""

"""The planner's one error: what was refused (`what`: path, reach, bounds, grid, file...) and why."""


class PlanError(ValueError):
    def __init__(self, what: str, reason: str) -> None:
        super().__init__(f"{what}: {reason}")
        self.what = what
        self.reason = reason

"""The actuators' limits (the report's section 1.2).

Constant torque limits are the report's example: lower <= u <= upper. DC servo motors give state-dependent ones:
a motor's torque at voltage V and speed w is (k_t/R) V - (k_t k_e/R) w, so what the voltage limits bound is

    lower <= u + K q' <= upper,     K = k_t k_e / R (per joint, N m s/rad, at the joint),  lower/upper = k_t V/R

which is the report's V = a s'' + b s'^2 + d s' + c with d(s) = K dq/ds (the report writes the same with the
opposite sign convention for K, "u = V + K q'"). `back_emf` zero is the constant-torque case.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from host_tools.plan.errors import PlanError


@dataclass(frozen=True)
class Limits:
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    back_emf: Optional[tuple[float, ...]] = None      # K per joint; None: constant torque limits

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if lo.shape != hi.shape or lo.ndim != 1:
            raise PlanError("bounds", "lower and upper limits need one value per joint")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi <= lo):
            raise PlanError("bounds", "every joint needs finite limits with lower < upper")
        if self.back_emf is not None:
            k = np.asarray(self.back_emf, float)
            if k.shape != lo.shape or not np.all(np.isfinite(k)) or np.any(k < 0):
                raise PlanError("bounds", "back_emf needs one finite value per joint, not negative")

    @classmethod
    def symmetric(cls, limits: Sequence[float], back_emf: Optional[Sequence[float]] = None) -> "Limits":
        return cls(tuple(-float(v) for v in limits), tuple(float(v) for v in limits),
                   None if back_emf is None else tuple(float(k) for k in back_emf))

    @property
    def lo(self) -> np.ndarray:
        return np.asarray(self.lower, float)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray(self.upper, float)

    @property
    def state_dependent(self) -> bool:
        return self.back_emf is not None and any(self.back_emf)

    def d(self, q_s: np.ndarray) -> np.ndarray:
        """The velocity term d(s) (N, dof) of the bounded quantity a s'' + b s'^2 + d s' + c."""
        return np.zeros_like(q_s) if self.back_emf is None else q_s * np.asarray(self.back_emf, float)

    def describe(self) -> dict:
        return {"lower": list(self.lower), "upper": list(self.upper),
                "back_emf": None if self.back_emf is None else list(self.back_emf)}

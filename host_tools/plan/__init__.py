"""The report's trajectory planning (section "Trajectory planning", pp. 1-4 of its planning part): two planar
two-link arms carrying one object along a path w(s), planned time-optimally on the phase plane and
energy-optimally by dynamic programming. Host side only: nothing here depends on the firmware or the plant.

    paths.py     the object's path w(s) and its derivatives in s
    model.py     the two arms, their kinematics and dynamics, the object, the parameterized dynamics
    bounds.py    the actuators' limits: constant torques, or DC motors' voltages (state-dependent)
    phase.py     the phase plane: pseudo-acceleration bounds, the maximum velocity curve, the integrators
    timeopt.py   time-optimal planning the report's way (switching points, limit curves)
    energy.py    dynamic programming on the (s, s') grid, with the report's and other objectives
    example.py   the report's numerical example
"""

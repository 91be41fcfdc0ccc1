"""What the arm and the tracker do for a user: kinematics and the demo scene, the pick-and-place
run, the demo, the tracker's simulated day."""

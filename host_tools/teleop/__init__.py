"""`aspod teleop`: the session, its words, the console and how replies, events and telemetry read."""

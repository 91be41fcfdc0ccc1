"""The exit codes of every `aspod` command (and of a teleop script), in one place.

    0  OK       everything asked for was done
    1  FAILED   a command was refused or failed, a motion did not end DONE, an `expect` was not met
    2  USAGE    bad arguments or input (a bad option, file, script line); nothing was run
    3  LINK     the link to the controller could not be made or was lost
"""
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_LINK = 0, 1, 2, 3

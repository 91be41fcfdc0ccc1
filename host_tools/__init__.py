"""Host-side tools: the `aspod` command line and the assembly of controller + plant.

This is the only package that imports firmware_py and hil_sim together; nothing imports it.
"""

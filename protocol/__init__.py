"""The wire: the framed host<->controller link protocol and the HAL bus declaration.

Imports none of firmware_py, hil_sim or host_tools; any host program may use it alone.
"""

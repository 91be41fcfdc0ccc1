"""The hardware the ASPOD controller drives, simulated: the plant and its end of the HAL bus.

It meets the controller only on the HAL bus (`protocol.hal`), as real hardware would,
and never imports `firmware_py`. `plant` holds the physics (no bus, no clock: it is
stepped by `dt_s`); `hal_node` puts it on a python-can bus and is run as a scheduler
task that takes `now`.
"""

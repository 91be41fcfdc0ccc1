"""The wire: the framed host<->controller link protocol and the HAL bus declaration.

Imports none of firmware_py, hil_sim or host_tools; any host program may use it alone.
"""
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason

__all__ = ["PROTOCOL_VERSION", "SCHEMA", "Reason"]

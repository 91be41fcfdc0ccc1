"""The ASPOD controller: an embedded-style firmware process in Python.

It meets the plant only on the HAL bus (`protocol.hal`) and the host only on the
framed link (`protocol.link`); see docs/Code_Overview.md.
"""

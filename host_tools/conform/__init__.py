"""`aspod conform`: a conformance suite for any controller speaking the link protocol (docs/conformance.md)."""

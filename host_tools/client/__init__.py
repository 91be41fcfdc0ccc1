"""The host's end of the link, as one interface: `HostClient` over a real port in real time
(`live`), `BenchClient` on a lock-step bench on the simulated clock (`bench`)."""

"""Live vehicle state in over UDP: one decoder per game format, a receiver that never blocks the
loop, and a common `VehicleState` in SI units (NaN where a format does not carry a field).

Nothing here is imported by the loop unless `--telemetry` asks for it.
"""

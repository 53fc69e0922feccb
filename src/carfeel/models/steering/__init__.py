"""Steering wheel torque (section 2 of the paper)."""

"""Gearshift models: one gear engagement along x (1 DOF)."""

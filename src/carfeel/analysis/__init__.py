"""Figures computed from results or logs: shift features, steering feel metrics."""

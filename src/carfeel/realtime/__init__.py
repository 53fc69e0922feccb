"""The haptic loop: fixed-rate rendering of the models on force-feedback devices, safely."""

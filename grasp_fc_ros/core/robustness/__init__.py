"""Robustness of force closure to contact errors."""

from .probability import ForceClosureProbability, probability_of_force_closure

__all__ = ["ForceClosureProbability", "probability_of_force_closure"]

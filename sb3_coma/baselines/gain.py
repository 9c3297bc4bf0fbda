"""Expected information gain of camera footprints: now lives in :mod:`envs.gain` (the env computes
each UAV's per-action gain for its observation); re-exported here for the planners."""
from envs.gain import WEIGHTINGS, axis_counts, footprint_fraction, footprint_gains, gain_density

__all__ = ["WEIGHTINGS", "axis_counts", "footprint_fraction", "footprint_gains", "gain_density"]

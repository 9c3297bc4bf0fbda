"""Observation layout shared by the environment, the fusion wrappers and the learners.

Every map is aligned with the field: row index = y lattice index, column index = x lattice index,
so cell ``[j, i]`` of an 11 x 11 map is the lattice column at ``(x, y) = (5 i, 5 j)`` metres.
Keeping the channel numbers in one module means the env, the fusion wrappers, COMA's critic and
the planners cannot drift apart.
"""

from __future__ import annotations

#: Side of the decision lattice and of every observation map.
LATTICE = 11
#: Number of discrete actions (0 up, 1 -x, 2 -y, 3 +y, 4 +x, 5 down).
N_ACTIONS = 6
ACTION_NAMES = ("up", "-x", "-y", "+y", "+x", "down")

# Channels of ``obs["local"]``. The raw env emits the first 7; a fusion wrapper appends FUSED.
BUDGET, AGENT_ID, ALTITUDE, FOOTPRINT, SENSOR, BELIEF, BELIEF_ENTROPY, FUSED = range(8)
RAW_LOCAL_CHANNELS = 7
LOCAL_CHANNELS = 8

# Channels of ``obs["state"]`` (critic only).
GLOBAL_BELIEF, GLOBAL_ENTROPY, GLOBAL_COVERAGE = range(3)
STATE_CHANNELS = 3

#: The critic's input: 8 local + 3 state + 1 "other UAVs' actions" channel it builds itself.
CRITIC_CHANNELS = LOCAL_CHANNELS + STATE_CHANNELS + 1

# Keys of the observation dict.
KEY_LOCAL = "local"
KEY_RECEIVED = "received"
KEY_RECEIVED_VALID = "received_valid"
KEY_STATE = "state"
KEY_MASK = "action_mask"
#: Optional key (env option ``action_gain``): (2, 6) each action's normalised expected information
#: gain, from the UAV's own local belief, under ipp-marl's class-weighted entropy (row 0) and
#: plain binary entropy (row 1); COMA's actor can add it to its logits (``gain_prior``).
KEY_GAIN = "action_gain"
GAIN_WEIGHTINGS = ("class", "plain")

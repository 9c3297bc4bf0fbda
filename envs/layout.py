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

# Observation v3 (env option ``observation="v3"``) appends to ``local``, after FUSED:
#: INTENT: where teammates whose message arrived this step are heading (1 at the column each
#: reaches if it repeats the move it made this step; the move travels in the message).
INTENT = LOCAL_CHANNELS
#: then the fine view of M_i: the comm grid's (2, R, R) mean belief and entropy, space-to-depth
#: onto the lattice (R = FINE_FACTOR * LATTICE), belief sub-cells first, row-major.
FINE_VIEW = INTENT + 1
FINE_FACTOR = 4
FINE_CHANNELS = 2 * FINE_FACTOR * FINE_FACTOR
#: Channels v3 adds to ``local`` (raw env and after fusion alike).
V3_LOCAL_EXTRA = 1 + FINE_CHANNELS

# Channels of ``obs["state"]`` (critic only).
GLOBAL_BELIEF, GLOBAL_ENTROPY, GLOBAL_COVERAGE = range(3)
STATE_CHANNELS = 3
#: Observation v3's privileged critic channels (ground truth; the critic never flies): the
#: fraction of truly valuable cells per block and the global belief's mean per-cell error |p - truth|.
VALUABLE_FRACTION, BELIEF_ERROR = range(STATE_CHANNELS, STATE_CHANNELS + 2)
V3_STATE_EXTRA = 2

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

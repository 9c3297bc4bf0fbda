"""How every figure tells its methods apart: colour, line style and marker, never colour alone.

About one reader in twelve does not tell red from green, and a figure printed in grey loses
colour altogether, so each method gets a colour of Okabe and Ito's colour-blind-safe palette
("Color Universal Design", 2008) *and* a line style *and* a marker of its own: any one of the
three is enough to follow a line. The well-known methods keep one style across every figure
(``coma`` is always the blue solid line with circles, ``ag`` the vermillion dashed one with
squares); other labels take the free styles in the order they come.

No matplotlib import here: :mod:`sb3_coma.experiments.learning_curves` draws on a bare
``Figure`` without pyplot and :mod:`sb3_coma.experiments.plots` selects the Agg backend; both
read their styles from this module.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

#: Titles of the noise sweep's axes (the channel options it sweeps) in its figure.
AXIS_TITLES: dict[str, str] = {"sigma": "sigma", "alpha_low": "a_low", "drop_probability": "drop p"}

#: Okabe & Ito's eight colours, ordered so that the first ones contrast most on white: blue,
#: vermillion, bluish green, reddish purple, orange, sky blue, black, yellow (last: faint on white).
OKABE_ITO: tuple[str, ...] = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442")
#: Eight line styles matplotlib tells apart (the last four as (offset, on-off dash sequence)).
LINESTYLES: tuple[str | tuple[int, tuple[int, ...]], ...] = (
    "-",
    "--",
    "-.",
    ":",
    (0, (5, 1)),
    (0, (3, 1, 1, 1, 1, 1)),
    (0, (8, 2, 2, 2)),
    (0, (1, 3)),
)
MARKERS: tuple[str, ...] = ("o", "s", "^", "D", "v", "P", "X", "*")
#: Bar fills that survive greyscale printing (bar charts have no line style or marker).
HATCHES: tuple[str, ...] = ("", "//", "..", "xx", "\\\\", "oo", "--", "++")

#: Style slot of the methods every study shows, so that each keeps its look across figures.
_PREFERRED: dict[str, int] = {
    "coma": 0,
    "ours": 0,
    "ag": 1,
    "ag-k3": 2,
    "lawnmower": 3,
    "nl": 3,
    "oracle": 4,
    "ag-k2": 5,
    "random": 6,
    "ag-comm": 7,
}


@dataclass(frozen=True)
class MethodStyle:
    """The look of one method: matplotlib's ``color``, ``linestyle``, ``marker`` and a bar ``hatch``."""

    color: str
    linestyle: str | tuple[int, tuple[int, ...]]
    marker: str
    hatch: str

    def line(self) -> dict[str, Any]:
        """Keyword arguments of ``Axes.plot`` / ``Axes.errorbar`` for this style."""
        return {"color": self.color, "linestyle": self.linestyle, "marker": self.marker}


def _slot_style(slot: int) -> MethodStyle:
    """Slot ``k``: colour, line style and marker of index ``k`` (mod 8); past eight methods the line
    style and the marker shift against the colour, so no two slots share all three below 64."""
    n = len(OKABE_ITO)
    turn = slot // n
    return MethodStyle(
        color=OKABE_ITO[slot % n],
        linestyle=LINESTYLES[(slot + turn) % len(LINESTYLES)],
        marker=MARKERS[(slot + 2 * turn) % len(MARKERS)],
        hatch=HATCHES[(slot + turn) % len(HATCHES)],
    )


def _preferred_slot(label: str) -> int | None:
    """The fixed slot of a well-known method: its name, or a label that starts with it and a
    space or bracket (``"COMA (oracle warm start)"``, ``"ag (class)"``)."""
    key = label.strip().lower()
    if key in _PREFERRED:
        return _PREFERRED[key]
    for name, slot in _PREFERRED.items():
        if key.startswith((f"{name} ", f"{name}(", f"{name}[")):
            return slot
    return None


def method_styles(labels: Iterable[str]) -> dict[str, MethodStyle]:
    """A distinct style for each label (duplicates share theirs): well-known methods their own
    slot when it is free, the others the lowest free slots, in the order given."""
    unique = list(dict.fromkeys(labels))
    taken: dict[str, int] = {}
    for label in unique:
        slot = _preferred_slot(label)
        if slot is not None and slot not in taken.values():
            taken[label] = slot
    free = (k for k in range(10**6) if k not in taken.values())
    for label in unique:
        if label not in taken:
            taken[label] = next(free)
    return {label: _slot_style(taken[label]) for label in unique}


def uav_colour(index: int) -> str:
    """Colour of UAV ``index`` in mission pictures (the palette in turn)."""
    return OKABE_ITO[index % len(OKABE_ITO)]

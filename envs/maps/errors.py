"""The one exception type of :mod:`uav_ipp.maps`.

It lives in its own module so that the rule parser, the image reader and the loader can all raise
it without importing one another.
"""

from __future__ import annotations


class MapError(ValueError):
    """A map name, file, rule or size that cannot give a ground truth.

    Subclasses :class:`ValueError` so that callers which already guard configuration with
    ``except ValueError`` keep working; every message names the offending value and what is allowed,
    because these errors surface at the top of a training run where a traceback into cv2 or numpy
    would not tell the user what to change.
    """

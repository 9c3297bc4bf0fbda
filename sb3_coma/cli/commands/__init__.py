"""Sub-commands of ``sb3-coma``: one module each (``NAME``, ``HELP``, ``add_arguments``, ``run``).

The options they share (``--threads``, ``--workers``, ``--env``, ``--seed``, ``--missions``,
``--out``) are defined once in :mod:`sb3_coma.app.arguments`, with the studies' parsers.
"""

from __future__ import annotations

from sb3_coma.app.arguments import add_workers_argument, default_map, workers_value

__all__ = ["add_workers_argument", "default_map", "workers_value"]

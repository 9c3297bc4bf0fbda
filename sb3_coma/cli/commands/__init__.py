"""Sub-commands of ``sb3-coma``: one module each (``NAME``, ``HELP``, ``add_arguments``, ``run``)."""

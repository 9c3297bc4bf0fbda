"""What the algorithms share: the multi-agent vec env and its contract (``joint``), masking,
extractors, callbacks, checkpoint files and evaluation of objects. It imports no algorithm
(``coma``, ``mappo``), no UAV policy and nothing of the application."""

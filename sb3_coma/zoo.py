"""``python -m sb3_coma.zoo train|enjoy ...``: rl-zoo3's own commands with ``--algo coma``.

The code lives in the application layer, :mod:`sb3_coma.app.zoo`.
"""

import sys

from sb3_coma.app.zoo import main

if __name__ == "__main__":
    sys.exit(main())

"""``python -m sb3_coma`` is the ``sb3-coma`` command line."""

import sys

from sb3_coma.cli import main

sys.exit(main())

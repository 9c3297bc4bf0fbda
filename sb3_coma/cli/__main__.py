"""``python -m sb3_coma.cli`` is the ``sb3-coma`` command line (as is ``python -m sb3_coma``)."""

import sys

from sb3_coma.cli import main

sys.exit(main())

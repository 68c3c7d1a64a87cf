"""``python -m dcmotor_id.cli.main``: the command line, as ``dcmotor-id``."""

import sys

from dcmotor_id.cli.main import main

sys.exit(main())

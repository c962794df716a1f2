"""``python -m rotmod.cli``: the ``rotmod`` command line."""

import sys

from rotmod.cli import main

sys.exit(main())

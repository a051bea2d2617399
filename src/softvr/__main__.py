"""``python -m softvr`` is the ``softvr`` command."""

import sys

from softvr.cli import main

sys.exit(main())

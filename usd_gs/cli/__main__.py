"""``python -m usd_gs.cli``: the ``usdgs`` command."""

import sys

from usd_gs.cli import main

sys.exit(main())

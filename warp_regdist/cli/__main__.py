"""``python -m warp_regdist.cli``: the same as the ``warp-regdist`` command."""

import sys

from . import main

sys.exit(main())

"""``python -m se3push``: the ``se3push`` command (what ``torchrun -m se3push train`` runs)."""

import sys

from se3push.cli import main

sys.exit(main())

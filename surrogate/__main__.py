"""``python -m surrogate``: the same as the ``surrogate`` command."""

import sys

from ._cli import main

sys.exit(main())

"""``python -m derive`` is the same as the ``dq-derive`` command."""

import sys

from .cli import main

sys.exit(main())

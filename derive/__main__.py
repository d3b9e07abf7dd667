"""``python -m derive`` is the same as the ``dq-derive`` command."""

import sys

from derive.cli import main

sys.exit(main())

"""``python -m api.cli ...``: the same as the ``airpuff`` command."""

import sys

from . import main

sys.exit(main())

"""``python -m app.cli``: the ``mocap-index`` command."""

import sys

from app.cli import main

sys.exit(main())

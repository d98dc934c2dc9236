"""``python -m embagents.cli``: the ``embagents`` command."""

import sys

from embagents.cli import main

sys.exit(main())

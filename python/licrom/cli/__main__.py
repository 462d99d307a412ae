"""``python -m licrom.cli``: the ``licrom`` command (:func:`licrom.cli.commands.main`), where its script is not on PATH."""

import sys

from .commands import main

sys.exit(main())

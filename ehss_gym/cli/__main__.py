"""``python -m ehss_gym.cli``: the ``ehss`` command."""

import sys

from . import main

sys.exit(main())

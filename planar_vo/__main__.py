"""``python -m planar_vo``: the same as the ``planar_vo`` command."""

import sys

from planar_vo.cli import main

sys.exit(main())

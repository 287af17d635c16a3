"""``python -m service.cli``: the ``impactcell`` command."""

import sys

from service.cli import main

sys.exit(main())

"""``python -m service.cli``: the ``impactcell`` command."""

from service.cli import entry

entry()

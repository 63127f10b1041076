"""`python -m jaxhop`: the `jaxhop` command line."""

import sys

from ._cli.main import command

sys.exit(command())

"""Where jaxhop keeps what it computes once: plans, the SLIP table, compiled programs."""

import os


def cache_dir() -> str:
    """`$JAXHOP_CACHE`, default `~/.cache/jaxhop`."""
    return os.environ.get("JAXHOP_CACHE", os.path.join(os.path.expanduser("~"), ".cache",
                                                       "jaxhop"))

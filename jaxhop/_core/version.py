"""jaxhop's version: the one place it is written (the package metadata reads it here too).

Plans, SLIP tables and checkpoints on disk carry it, so an upgrade never loads a file an
older version wrote.
"""

VERSION = "0.2.0"

import os
import tempfile

import jax

jax.config.update("jax_enable_x64", True)
# Tests never touch the user's plan cache.
os.environ.setdefault("JAXHOP_CACHE", tempfile.mkdtemp(prefix="jaxhop-test-cache-"))

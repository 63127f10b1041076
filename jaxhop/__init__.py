"""jaxhop: reactive footstep planning for spring-mass hopping on rough terrain, in JAX."""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from ._errors import InputError as InputError

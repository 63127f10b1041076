"""Write `jaxhop/data/template_boxes.npz`: the template boxes of the built-in templates.

`relative_boxes` computes a plan's template boxes op by op, which costs a fresh process
about 6 s; the built-in templates' boxes ship with jaxhop instead (docs/planning.md). Run
this after a change to the templates or the regions; `tests/test_plan.py` checks the file
against the boxes computed anew.

    python docs/make_template_boxes.py
"""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jaxhop import Hopper  # noqa: E402
from jaxhop._planning.plan import templates_for  # noqa: E402
from jaxhop._planning.stages import SHIPPED_BOXES, box_key, computed_boxes  # noqa: E402

if __name__ == "__main__":
    hopper = Hopper()
    boxes = {box_key(t, hopper): computed_boxes(t, hopper)
             for t in (templates_for("bhop"), templates_for("slip"))}
    np.savez(SHIPPED_BOXES, **boxes)
    print(f"wrote {SHIPPED_BOXES}: {', '.join(boxes)}")

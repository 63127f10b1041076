"""Time one snapshot's incremental update against full rebuilds, repeated
(docs/parkour_reactive.md, "Incremental replanning").

`parkour_compare.py --timing` times each update inside the course's update chain and
rebuilds once; this script isolates one snapshot: the plan of the snapshot before it is
built first, then the update is timed `--updates` times and the full rebuild `--rebuilds`
times (after one untimed run of each, so that nothing includes compilation), all in one
process, and the medians are compared.

    python benchmarks/parkour_update_one.py --course mppc-hw-dynamic-4 --snapshot 2
    python benchmarks/parkour_update_one.py --course mppc-hw-dynamic-4 --snapshot 2 --model slip

`--model slip` uses the leg's SLIP templates (`leg_templates(h, model="slip")`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from jaxhop.mppc import load_course
from jaxhop.parkour import (
    COURSE_GRID,
    build_course_plan,
    course_map,
    identical_plans,
    leg_hopper,
    leg_templates,
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--course", required=True)
    ap.add_argument("--snapshot", type=int, required=True, help="1-based snapshot index")
    ap.add_argument("--updates", type=int, default=6)
    ap.add_argument("--rebuilds", type=int, default=3)
    ap.add_argument("--centred", dest="align", action="store_false",
                    help="every block's segments centred")
    ap.add_argument("--model", choices=["bhop", "slip"], default="bhop",
                    help="the leg's BHop or SLIP templates")
    ap.add_argument("--json", metavar="PATH")
    args = ap.parse_args(argv)
    course = load_course(args.course)
    if not 1 <= args.snapshot <= len(course.snapshots):
        ap.error(f"--snapshot: {args.course} has {len(course.snapshots)} snapshots")
    hop = leg_hopper()
    tm = leg_templates(hop, model=args.model)
    envs = [course.environment] + [e for _, e in course.snapshots]
    maps = [course_map(course, e, hop, align=args.align) for e in envs[: args.snapshot + 1]]
    prev = build_course_plan(maps[0], tm, hop, grid=COURSE_GRID)
    for m in maps[1:-1]:
        prev = build_course_plan(m, tm, hop, grid=COURSE_GRID, previous=prev)
    m = maps[-1]

    def timed(**kw):
        t0, c0 = time.perf_counter(), time.process_time()
        plan = build_course_plan(m, tm, hop, grid=COURSE_GRID, **kw)
        return plan, time.perf_counter() - t0, time.process_time() - c0

    timed(previous=prev)
    timed()
    up = [timed(previous=prev) for _ in range(args.updates)]
    rb = [timed() for _ in range(args.rebuilds)]
    uw, uc = np.median([u[1] for u in up]), np.median([u[2] for u in up])
    rw, rc = np.median([r[1] for r in rb]), np.median([r[2] for r in rb])
    same = all(identical_plans(u[0], rb[0][0]) for u in up)
    out = {"course": args.course, "snapshot": args.snapshot, "align": args.align,
           "model": args.model,
           "update_s": [u[1] for u in up], "update_cpu_s": [u[2] for u in up],
           "rebuild_s": [r[1] for r in rb], "rebuild_cpu_s": [r[2] for r in rb],
           "ratio": rw / uw, "ratio_cpu": rc / uc, "identical": same}
    print(f"{args.course} snapshot {args.snapshot} ({args.model}): update median {uw:.2f} s "
          f"(cpu {uc:.2f}), "
          f"rebuild median {rw:.1f} s (cpu {rc:.1f}), ratio {rw / uw:.2f} "
          f"(cpu {rc / uc:.2f}), identical {same}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

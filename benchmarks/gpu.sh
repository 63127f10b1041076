#!/usr/bin/env bash
# On a machine with a GPU: time the reference BHop and SLIP sweeps and the plan build there
# and on two CPU cores of the same machine, in one run, and write
# benchmarks/results/<device>-gpu-<yyyy-mm>.json (benchmarks/gpu.py says how).
#
#   benchmarks/gpu.sh [extra arguments of benchmarks/gpu.py]
#
# Runs from a checkout without installing (PYTHONPATH); plans and the SLIP table come from
# $JAXHOP_CACHE (copy a warm cache there to skip building them). About 7 minutes on one
# H200 machine with 16 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
python3 -c "import jax; print(jax.__version__, jax.devices())"
device=$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1 | awk '{print tolower($2)}')
out="benchmarks/results/${device:-gpu}-gpu-$(date +%Y-%m).json"
python3 -c "
import jaxhop, jaxhop.slip
for model in ('bhop', 'slip'):
    jaxhop.get_plan(jaxhop.builtin_terrain('reference'), templates=jaxhop.templates_for(model),
                    progress=False)
jaxhop.slip.slip_table(progress=False)"
python3 benchmarks/gpu.py --json "$out" "$@"
echo "wrote $out"

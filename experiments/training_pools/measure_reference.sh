#!/usr/bin/env bash
# Issue 42: the older Stage II checkpoints (shipped then, kept in this study's checkpoints/) on the multi-part pool's 32 held-out scenes
# (reconstructed conditions; Table 2's measure as run.sh scores its trainings). Resumable.
#   WORK=data/parts_pool experiments/training_pools/measure_reference.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
WORK=${WORK:-data/parts_pool}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
for ck in stage2_pool_recon stage2_small stage2_pool_trunc_snr; do
  out="$WORK/runs/ref/$ck/eval"
  [ -f "$out/scores.json" ] || .venv/bin/python -m gspi.stage2.evaluate_points "experiments/training_pools/checkpoints/$ck.pt" "$WORK/rpool64" \
    "$out" --num-steps 10 --max-points 20000 --baseline-train "$WORK/pool64" >> "$WORK/measure_reference.log" 2>&1
  echo "$(date -u +%FT%TZ) $ck done" >> "$WORK/measure_reference.log"
done

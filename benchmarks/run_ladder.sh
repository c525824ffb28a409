#!/usr/bin/env bash
# The learnability ladder (docs/STAGE2.md "Where the signal is lost"): R1-R5 x 3 seeds, each
# trained on the same 64 pool scenes with one thread, then scored with Table 2's measure on
# the 32 held-out pool scenes and the 4 `small` test scenes. Two lanes run side by side (one
# per core): lane A the diffusion model R5 (gspi-train, stage2=table2_cpu) and its evaluation,
# lane B the direct regressors R1-R4 (python -m gspi.stage2.ladder). Finished runs are skipped,
# so a rerun continues. Data (once, ~5 min on 2 cores):
#   gspi-data preset=stage2_pool out=$POOL_ROOT seed=0 'data.pool_indices=[[0,64],[224,256]]' data.workers=2
#   python -m gspi.data.pool_split $POOL_ROOT $POOL --train 0:64 --test 224:256
#   gspi-data preset=small out=$SMALL seed=0 'data.only_splits=[test]'
# Usage: benchmarks/run_ladder.sh POOL SMALL RUNS [SEEDS...]
set -u
POOL=$1; SMALL=$2; RUNS=$3; shift 3
SEEDS=${*:-0 1 2}
PY=${PY:-.venv/bin/python}
export OMP_NUM_THREADS=1
mkdir -p "$RUNS"

lane_a() {
  for s in $SEEDS; do
    d=$RUNS/r5_s$s
    [ -f "$d/stats.json" ] || $PY -m gspi.cli.train data="$POOL" out="$d" stage2=table2_cpu ablation=full seed=$s \
      > "$RUNS/r5_s$s.log" 2>&1 || echo "r5 seed $s failed (see $RUNS/r5_s$s.log)"
  done
  for s in $SEEDS; do
    d=$RUNS/r5_s$s
    for e in heldout small; do
      [ -f "$d/eval_$e/scores.json" ] && continue
      if [ $e = heldout ]; then data=$POOL; else data=$SMALL; fi
      $PY -m gspi.stage2.evaluate_points "$d/checkpoint.pt" "$data" "$d/eval_$e" --num-steps 10 \
        --max-points 20000 --baseline-train "$POOL" >> "$RUNS/r5_s$s.eval.log" 2>&1 \
        || echo "r5 seed $s eval $e failed"
    done
  done
}

lane_b() {
  for r in r1 r2 r3 r4; do
    for s in $SEEDS; do
      d=$RUNS/${r}_s$s
      [ -f "$d/eval_small/scores.json" ] && continue
      $PY -m gspi.stage2.ladder train --rung $r --seed $s --data "$POOL" --out "$d" \
        --eval heldout="$POOL":test --eval small="$SMALL":test > "$RUNS/${r}_s$s.log" 2>&1 \
        || echo "$r seed $s failed (see $RUNS/${r}_s$s.log)"
    done
  done
}

lane_a & lane_b & wait
$PY -m gspi.stage2.ladder summary "$RUNS"/*/eval_heldout > "$RUNS/summary_heldout.md"
$PY -m gspi.stage2.ladder summary "$RUNS"/*/eval_small > "$RUNS/summary_small.md"
cat "$RUNS/summary_heldout.md" "$RUNS/summary_small.md"

#!/usr/bin/env bash
# The learnability ladder (docs/log/stage2.md "Where the signal is lost"): R1-R5 x 3 seeds, each
# trained on the same 64 pool scenes with one thread, then scored with Table 2's measure on
# the 32 held-out pool scenes and the 4 `small` test scenes. Two workers (one per core) take
# jobs from one ordered list (a job is claimed by creating $RUNS/.claims/<job> atomically):
# the diffusion model R5 (gspi-train, stage2=table2_cpu) and its evaluation, and the direct
# regressors R1-R4 (python -m experiments.ladder.ladder). Finished jobs are skipped, so a rerun
# continues (remove $RUNS/.claims first if a run was killed). Data (once, ~5 min on 2 cores):
#   gspi-data preset=stage2_pool out=$POOL_ROOT seed=0 'data.pool_indices=[[0,64],[224,256]]' data.workers=2
#   python -m gspi.data.pool.split $POOL_ROOT $POOL --train 0:64 --test 224:256
#   gspi-data preset=small out=$SMALL seed=0 'data.only_splits=[test]'
# Diffusion rungs are name=recipe[:ablation] (a conf/stage2 preset, or this study's conf/stage2;
# ablation default full), e.g.
# the departures measured after R5: DIFFUSION_RUNGS="r6=table2_cpu_trunc_snr r6skip=table2_cpu_skip_trunc_snr"
# REGRESSOR_RUNGS=; or Table 2's variants on a recipe: "r6a1=table2_cpu_trunc_snr:a1_no_global_prior".
# Usage: experiments/ladder/run_ladder.sh POOL SMALL RUNS [SEEDS...]
set -u
POOL=$1; SMALL=$2; RUNS=$3; shift 3
SEEDS=${*:-0 1 2}
PY=${PY:-.venv/bin/python}
STUDY_CONF=$(cd "$(dirname "$0")" && pwd)/conf  # table2_cpu_skip*: this study's Stage II options
WORKERS=${WORKERS:-2}
DIFFUSION_RUNGS=${DIFFUSION_RUNGS-r5=table2_cpu}
REGRESSOR_RUNGS=${REGRESSOR_RUNGS-r1 r2 r3 r4}
export OMP_NUM_THREADS=1
mkdir -p "$RUNS/.claims"

declare -A RECIPE
JOBS=()
for pair in $DIFFUSION_RUNGS; do
  r=${pair%%=*}; RECIPE[$r]=${pair#*=}
  for s in $SEEDS; do JOBS+=("train $r $s"); done
done
for r in $REGRESSOR_RUNGS; do for s in $SEEDS; do JOBS+=("train $r $s"); done; done
for r in "${!RECIPE[@]}"; do for s in $SEEDS; do JOBS+=("eval $r $s"); done; done

is_diffusion() { [ -n "${RECIPE[$1]+x}" ]; }

done_already() {  # kind rung seed
  if [ $1 = train ] && is_diffusion $2; then [ -f "$RUNS/$2_s$3/stats.json" ]
  else [ -f "$RUNS/$2_s$3/eval_small/scores.json" ]; fi
}

run_job() {  # kind rung seed
  local d=$RUNS/$2_s$3
  if [ $1 = train ] && is_diffusion $2; then
    local spec=${RECIPE[$2]}; local abl=full
    [[ $spec == *:* ]] && abl=${spec#*:} && spec=${spec%%:*}
    $PY -m gspi.cli.train "hydra.searchpath=[file://$STUDY_CONF]" data="$POOL" out="$d" stage2=$spec ablation=$abl seed=$3 > "$d.log" 2>&1
  elif [ $1 = train ]; then
    $PY -m experiments.ladder.ladder train --rung $2 --seed $3 --data "$POOL" --out "$d" \
      --eval heldout="$POOL":test --eval small="$SMALL":test > "$d.log" 2>&1
  else
    while [ ! -f "$d/stats.json" ]; do sleep 20; done  # its training, on the other worker
    for e in heldout small; do
      if [ $e = heldout ]; then data=$POOL; else data=$SMALL; fi
      $PY -m gspi.stage2.evaluate_points "$d/checkpoint.pt" "$data" "$d/eval_$e" --num-steps 10 \
        --max-points 20000 --baseline-train "$POOL" >> "$d.eval.log" 2>&1 || return 1
    done
  fi
}

worker() {
  for job in "${JOBS[@]}"; do
    set -- $job
    done_already "$@" && continue
    mkdir "$RUNS/.claims/$1_$2_$3" 2>/dev/null || continue
    run_job "$@" || echo "$job failed (see $RUNS/$2_s$3*.log)"
  done
}

for w in $(seq "$WORKERS"); do worker & done
wait
$PY -m experiments.ladder.ladder summary "$RUNS"/*/eval_heldout > "$RUNS/summary_heldout.md"
$PY -m experiments.ladder.ladder summary "$RUNS"/*/eval_small > "$RUNS/summary_small.md"
cat "$RUNS/summary_heldout.md" "$RUNS/summary_small.md"

#!/usr/bin/env bash
# A study driver (issue 42; Table 2 itself is `gspi-reproduce table=2 scale=cpu`, docs/REPRODUCE.md): the multi-part training pool, its Stage 0 reconstructions, the trainings of a Stage II
# recipe (2 seeds) and Table 2's measure on the held-out pool scenes. Every step is resumable:
# rerun this script after a cut-off session and it continues where it stopped (complete.json,
# reconstructed.json, the training's checkpoint.pt, scores.json mark what is done).
#
#   WORK=data/parts_pool SEEDS="0 1" CHUNK_MIN=40 nohup setsid experiments/training_pools/run.sh &
#   WORK=data/parts_pool RECIPE=cpu_parts_pool_s nohup setsid experiments/training_pools/run.sh &
#   # session 15's look-swap pool: train scenes only, measured on the parts pool's held-out scenes
#   WORK=data/looks_pool RECIPE=cpu_parts_pool PARTS_EXTRA=data.parts.look_swap=0.5 \
#     POOL_INDICES='[[0,64]]' SPLIT='--train 0:64' HELDOUT=data/parts_pool \
#     nohup setsid experiments/training_pools/run.sh &
#   # session 16's matte-finish pool (the default's recipe); ABLATION=a1_no_global_prior etc.: a Table 2 row
#   WORK=data/matte_pool RECIPE=cpu_parts_pool PARTS_EXTRA=data.parts.matte_finish=0.5 \
#     POOL_INDICES='[[0,64]]' SPLIT='--train 0:64' HELDOUT=data/parts_pool [ABLATION=a1_no_global_prior SEEDS=0] \
#     nohup setsid experiments/training_pools/run.sh &
#   # session 18: the same, trained on each scene under reconstructed AND exact conditions
#   # (experiments/training_pools/mix_conditions.py; runs/<RECIPE>_mix_s<seed>)
#   WORK=data/matte_pool ... CONDITIONS=mixed nohup setsid experiments/training_pools/run.sh &
#   # session 20's default (stage2_pool224_pixel.pt): the same with TAG=pixel TRAIN_EXTRA=stage2.data.pixel_features=true
#   # (runs/<RECIPE>_pixel_224_s<seed>); session 19's default (stage2_pool224.pt): the matte pool's 224 training scenes (runs/<RECIPE>_224_s<seed>;
#   # with CONDITIONS=mixed runs/<RECIPE>_mix224_s<seed>)
#   WORK=data/matte_pool RECIPE=cpu_parts_pool PARTS_EXTRA=data.parts.matte_finish=0.5 \
#     POOL_INDICES='[[0,224]]' SPLIT='--train 0:224' TRAIN_SCENES=224 HELDOUT=data/parts_pool \
#     nohup setsid experiments/training_pools/run.sh &
#
# PLAN_ONLY=1 prints the run names and data it would use and stops.
# Progress: $WORK/run.log; finished training chunks: docs/log/stage2_runs.jsonl (committed); each
# run's held-out scores: results/heldout/cpu/<run>_s<seed>/scores.json (commit them: $WORK may not survive).
# Two cores: data and reconstruction use 2 workers of one thread; the seeds train side by side,
# one thread each.
# The body is one { ... } group, so bash reads all of it before running any: editing this file
# while a run is in flight cannot change what that run does next.
{
set -euo pipefail
STUDY_CONF=$(cd "$(dirname "$0")" && pwd)/conf   # this study's Stage II options (RECIPE=cpu_parts_pool_s)
cd "$(dirname "$0")/../.."
WORK=${WORK:-data/parts_pool}
SEEDS=${SEEDS-"0 1"}                  # SEEDS="" builds the pool and its reconstructions, trains nothing
CHUNK_MIN=${CHUNK_MIN:-40}            # one gspi-train invocation (a chunk); checkpoints every 10 min inside
RECIPE=${RECIPE:-cpu_parts_pool}
POOL_INDICES=${POOL_INDICES:-'[[0,64],[224,256]]'}   # pool scenes generated (train, held out)
SPLIT=${SPLIT:-"--train 0:64 --test 224:256"}          # their roles (gspi.data.pool.split)
HELDOUT=${HELDOUT:-$WORK}             # whose rpool64 test split (and pool64 baseline) is measured
PARTS_EXTRA=${PARTS_EXTRA:-}          # more data.parts keys, e.g. data.parts.look_swap=0.5
ABLATION=${ABLATION:-full}            # conf/ablation/<name>: full or a Table 2 variant (a1..a5)
CONDITIONS=${CONDITIONS:-reconstructed}  # reconstructed (the paper) or mixed (+ the exact renders)
TRAIN_EXTRA=${TRAIN_EXTRA:-}          # more gspi-train overrides, e.g. stage2.data.pixel_features=true
TAG=${TAG:-}                          # names TRAIN_EXTRA's departure in the run names (required with it)
TRAIN_SCENES=${TRAIN_SCENES:-64}      # SPLIT's training scenes: names the views pool<N>, rpool<N>, mix<N>
case " $SPLIT " in *" --train 0:$TRAIN_SCENES "*) ;;
  *) echo "run.sh: TRAIN_SCENES=$TRAIN_SCENES but SPLIT='$SPLIT' does not train on 0:$TRAIN_SCENES" >&2; exit 2 ;; esac
if [ -n "$TRAIN_EXTRA" ] && [ -z "$TAG" ]; then
  echo "run.sh: TRAIN_EXTRA='$TRAIN_EXTRA' needs a TAG that names it in the run folders" >&2; exit 2; fi
RUN=$RECIPE; [ "$ABLATION" = full ] || RUN=${RECIPE}_$ABLATION   # runs/<RUN>_s<seed> (full keeps its old names)
[ -z "$TAG" ] || RUN=${RUN}_$TAG                # e.g. _pixel (session 20's default: TAG=pixel TRAIN_EXTRA=stage2.data.pixel_features=true)
VARIANT=""; [ "$CONDITIONS" = reconstructed ] || VARIANT=mix; [ "$TRAIN_SCENES" = 64 ] || VARIANT=$VARIANT$TRAIN_SCENES
[ -z "$VARIANT" ] || RUN=${RUN}_$VARIANT        # _mix, _224, _mix224
POOL_VIEW=$WORK/pool$TRAIN_SCENES; RECON_VIEW=$WORK/rpool$TRAIN_SCENES
SUMMARY=$WORK/recon_summary.md; [ "$TRAIN_SCENES" = 64 ] || SUMMARY=$WORK/recon_summary_$TRAIN_SCENES.md
TRAIN_DATA=$RECON_VIEW; [ "$CONDITIONS" = reconstructed ] || TRAIN_DATA=$WORK/mix$TRAIN_SCENES
BIN=.venv/bin
if [ -n "${PLAN_ONLY:-}" ]; then   # print what a run would train and measure, then stop
  echo "runs: $WORK/runs/${RUN}_s<seed> for seeds ${SEEDS:-none (pool and reconstructions only)}; train data: $TRAIN_DATA; held out: $HELDOUT/rpool64; train extra: ${TRAIN_EXTRA:-none}"
  exit 0
fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PARTS=(data.parts.share=0.6 data.parts.metal_f0=wide data.parts.roughness_spread=0.15 data.parts.texture=0.3 $PARTS_EXTRA)
mkdir -p "$WORK"
log() { echo "$(date -u +%FT%TZ) $*" | tee -a "$WORK/run.log"; }

log "pool: generate (indices $POOL_INDICES; ${PARTS[*]})"
$BIN/gspi-data preset=stage2_pool out="$WORK/pool" seed=0 "data.pool_indices=$POOL_INDICES" \
  data.workers=2 "${PARTS[@]}" >> "$WORK/run.log" 2>&1
$BIN/python -m gspi.data.pool.split "$WORK/pool" "$POOL_VIEW" $SPLIT >> "$WORK/run.log" 2>&1
log "pool: Stage 0 reconstructions"
if [ "$TRAIN_SCENES" != 64 ] && [ -d "$WORK/rpool64" ]; then   # reuse the 64-scene view's reconstructions
  $BIN/python -c "import sys; from pathlib import Path; from gspi.data.pool.split import link_scene
old, new = Path(sys.argv[1]), Path(sys.argv[2]); new.mkdir(parents=True, exist_ok=True)
for d in sorted(old.glob('p0*')): link_scene(new / d.name, d)" "$WORK/rpool64" "$RECON_VIEW"
fi
$BIN/python -m gspi.recon.reconstructed_pool "$POOL_VIEW" "$RECON_VIEW" --workers 2 >> "$WORK/run.log" 2>&1
$BIN/python -m gspi.recon.reconstructed_pool "$POOL_VIEW" "$RECON_VIEW" --summary > "$SUMMARY" 2>&1
case "$CONDITIONS" in
  reconstructed) ;;
  mixed) $BIN/python experiments/training_pools/mix_conditions.py "$RECON_VIEW" "$POOL_VIEW" "$WORK/mix$TRAIN_SCENES" >> "$WORK/run.log" 2>&1 ;;
  *) log "CONDITIONS=$CONDITIONS: expected reconstructed or mixed"; exit 2 ;;
esac
log "train: $RECIPE ablation=$ABLATION conditions=$CONDITIONS seeds $SEEDS (chunks of $CHUNK_MIN min)"
train_seed() {
  local seed=$1 out="$WORK/runs/${RUN}_s$1"
  until [ -f "$out/stats.json" ] && $BIN/python -c "import json,sys; s=json.load(open('$out/stats.json')); sys.exit(0 if s.get('steps',0)>=s.get('total_steps', 2500) else 1)"; do
    $BIN/gspi-train "hydra.searchpath=[file://$STUDY_CONF]" data="$TRAIN_DATA" out="$out" stage2=$RECIPE ablation=$ABLATION seed=$seed \
      stage2.train.stop_after_minutes=$CHUNK_MIN $TRAIN_EXTRA >> "$WORK/train_s$seed.log" 2>&1 \
      || { log "train: seed $seed failed (see $WORK/train_s$seed.log)"; return 1; }
    log "train: seed $seed chunk ended at step $($BIN/python -c "import json; print(json.load(open('$out/stats.json'))['steps'])")"
  done
}
pids=()
for s in $SEEDS; do train_seed "$s" & pids+=($!); done
for p in "${pids[@]}"; do wait "$p"; done
log "measure: Table 2's measure on the 32 held-out scenes of $HELDOUT (reconstructed conditions)"
for s in $SEEDS; do
  out="$WORK/runs/${RUN}_s$s"
  [ -f "$out/eval/scores.json" ] || $BIN/python -m gspi.stage2.evaluate_points "$out/checkpoint.pt" "$HELDOUT/rpool64" \
    "$out/eval" --num-steps 10 --max-points 20000 --baseline-train "$HELDOUT/pool64" >> "$WORK/run.log" 2>&1
  # the per-scene scores outlive $WORK (a lost data folder cost session 22 every run's scores):
  # committed copies that summary.py reads like the folder (NAME=results/heldout/cpu/<run>/scores.json)
  mkdir -p "results/heldout/cpu/${RUN}_s$s" && cp "$out/eval/scores.json" "results/heldout/cpu/${RUN}_s$s/scores.json"
done
log "done"
exit
}

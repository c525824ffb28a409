#!/usr/bin/env bash
# Issue 42: Table 2 at CPU scale with the shipped recipe (stage2=cpu_pool224: the matte pool's
# 224 training scenes, reconstructed conditions), every variant at SEEDS, measured on the parts
# pool's 32 held-out scenes. One command, resumable across sessions: each (variant, seed) is one
# experiments/parts_pool/run.sh call, which skips what finished and resumes a cut-off training
# from its last checkpoint (every 10 min). Two lanes share the list (job i runs in lane i mod LANES):
#
#   LANE=0 LANES=2 nohup setsid experiments/parts_pool/table2.sh > table2_lane0.out 2>&1 &
#   LANE=1 LANES=2 nohup setsid experiments/parts_pool/table2.sh > table2_lane1.out 2>&1 &
#   PLAN_ONLY=1 experiments/parts_pool/table2.sh     # the job list and each job's lane, then stop
#   TAG=pixel TRAIN_EXTRA=stage2.data.pixel_features=true LANE=0 LANES=2 ... # with today's default's
#     departure (run.sh passes TRAIN_EXTRA to every training but A1's and names the runs <recipe>_<variant>_pixel_224)
#
# Then the table: python experiments/parts_pool/summary.py --pool $HELDOUT/rpool64 \
#   full=$WORK/runs/cpu_parts_pool_224_s0/eval ... a1=$WORK/runs/cpu_parts_pool_a1_no_global_prior_224_s0/eval ... --reference full
# Costs per run (CPU-s on one thread, docs/log/stage2_runs.jsonl): Full ~1420, A1 ~270, A2 ~1200,
# A3 ~1830, A5 ~1400 (64-scene figures; the step count, not the pool size, sets them); A4 (384
# latents) is not in the default list: several CPU-hours per seed.
# The body is one { ... } group, so bash reads all of it before running any: editing this file
# while a run is in flight cannot change what that run does next.
{
set -euo pipefail
cd "$(dirname "$0")/../.."
WORK=${WORK:-/work/data/matte_pool}
HELDOUT=${HELDOUT:-/work/data/parts_pool}
SEEDS=${SEEDS:-"0 1 2"}
VARIANTS=${VARIANTS:-"full a2_no_view_onehot a5_multiview_injection a1_no_global_prior a3_npts_1024"}
LANE=${LANE:-0}; LANES=${LANES:-1}
TAG_ALL=${TAG:-}; EXTRA_ALL=${TRAIN_EXTRA:-}   # a recipe departure for every variant (run.sh's TAG / TRAIN_EXTRA)
jobs=(); for s in $SEEDS; do for v in $VARIANTS; do jobs+=("$v $s"); done; done
for i in "${!jobs[@]}"; do
  [ $((i % LANES)) = "$LANE" ] || continue
  read -r variant seed <<< "${jobs[$i]}"
  # A1 has no prior encoder, so no map to sample either (the config refuses pixel_features
  # without one): A1 drops that override, and with nothing else left it is the untagged run
  tag=$TAG_ALL; extra=$EXTRA_ALL
  if [ "$variant" = a1_no_global_prior ]; then
    extra=$(for w in $EXTRA_ALL; do case $w in stage2.data.pixel_features=*) ;; *) printf '%s ' "$w" ;; esac; done)
    extra=${extra% }; [ -n "$extra" ] || tag=
  fi
  if [ -n "${PLAN_ONLY:-}" ]; then echo "lane $LANE: $variant seed $seed${tag:+ [$tag: $extra]}"; continue; fi
  TAG=$tag TRAIN_EXTRA=$extra \
  WORK=$WORK RECIPE=cpu_parts_pool PARTS_EXTRA=data.parts.matte_finish=0.5 POOL_INDICES='[[0,224]]' \
    SPLIT='--train 0:224' TRAIN_SCENES=224 HELDOUT=$HELDOUT ABLATION=$variant SEEDS=$seed \
    experiments/parts_pool/run.sh
done
[ -n "${PLAN_ONLY:-}" ] || echo "$(date -u +%FT%TZ) table2 lane $LANE of $LANES: done"
exit
}

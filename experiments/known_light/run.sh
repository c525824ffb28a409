#!/usr/bin/env bash
# The known-light study end to end, resumable (each step skipped when its output exists):
#   experiments/known_light/run.sh [WORK]        # WORK defaults to $GSPI_DATA_ROOT/known_light or ~/.cache/gspi/known_light
#   experiments/known_light/run.sh WORK data     # only the datasets (after a lost WORK folder; then the rest resumes)
# ~10 min of data, ~40 min of Stage 0 (recon=fast) and ~10 min per fit condition on one thread of the 2-core VM.
set -euo pipefail
cd "$(dirname "$0")/../.."
WORK=${1:-${GSPI_DATA_ROOT:-$HOME/.cache/gspi}/known_light}
PY=${PY:-.venv/bin/python}
RES=experiments/known_light/results
BASE=experiments/view_dependence/log/retraining_shipped/exact_whole_xv_nbhd_s0.json   # its no-decomposition constants
KEYS="data.parts.share=0.6 data.parts.metal_f0=wide data.parts.roughness_spread=0.15 data.parts.texture=0.3"
export OMP_NUM_THREADS=1
mkdir -p "$WORK"
TRAIN_KEYS="$KEYS data.parts.matte_finish=0.5"
# Every dataset the study reads, each step skipped when its output exists (`run.sh WORK data` builds
# only these, ~40 min on 2 cores, the two pools side by side): the held-out pool of Table 2 (parts
# pool [224:256]; its checksums equal Table 2's records), 12 training-pool scenes [0:12] to choose
# the read-out's settings on (tune.py), the 64 training-pool scenes [0:64] (Table 2's training
# keys), and each pool's `recon=fast` assets with their Stage I clouds (light_geometry=asset).
heldout_data() {
  [ -f "$WORK/heldout_pool/p0255_capsule_rough_plastic/complete.json" ] || \
    .venv/bin/gspi-data preset=stage2_pool out="$WORK/heldout_pool" seed=0 'data.pool_indices=[[224,256]]' data.workers=1 $KEYS
  [ -d "$WORK/heldout_test" ] || $PY -m gspi.data.pool.split "$WORK/heldout_pool" "$WORK/heldout_test" --test 224:256
  [ -f "$WORK/tune_pool/p0011_superquadric_glossy_plastic/complete.json" ] || \
    .venv/bin/gspi-data preset=stage2_pool out="$WORK/tune_pool" seed=0 'data.pool_indices=[[0,12]]' data.workers=1 $KEYS
  $PY -m gspi.recon.reconstructed_pool "$WORK/heldout_test" "$WORK/rheldout_fast" --recon fast --workers 1
  $PY -m gspi.stage1.pool_clouds "$WORK/rheldout_fast"
}
training_data() {  # [SUFFIX KEYS]: train_pool<SUFFIX>, train_view<SUFFIX>, rtrain<SUFFIX>_fast drawn with KEYS
  local s=${1:-} keys=${2:-$TRAIN_KEYS}
  [ -f "$WORK/train_pool$s/p0063_sphere_painted_metal/complete.json" ] || \
    .venv/bin/gspi-data preset=stage2_pool out="$WORK/train_pool$s" seed=0 'data.pool_indices=[[0,64]]' data.workers=1 $keys
  [ -d "$WORK/train_view$s" ] || $PY -m gspi.data.pool.split "$WORK/train_pool$s" "$WORK/train_view$s" --train 0:64
  $PY -m gspi.recon.reconstructed_pool "$WORK/train_view$s" "$WORK/rtrain${s}_fast" --recon fast --workers 1
  $PY -m gspi.stage1.pool_clouds "$WORK/rtrain${s}_fast"
}
if [ "${2:-}" = data ]; then heldout_data & training_data; wait; exit 0; fi
heldout_data
training_data
[ -f "$RES/tune.json" ] || $PY -m experiments.known_light.tune "$WORK/tune_pool" --out "$RES/tune.json"
fit() {  # fit CONDITION VIEWS LIGHT LABEL
  [ -f "$RES/$1/knn_post/scores.json" ] || $PY -m experiments.known_light.fit "$WORK/heldout_test" "$2" \
    "$WORK/runs/$1" --baseline "$BASE" --light "$3" --results "$RES/$1" --label "$4"
}
fit exact_true "$WORK/heldout_test" true "parts_pool[224:256] (exact renders)"
[ -f "$RES/identify_exact.json" ] || $PY -m experiments.known_light.identify "$WORK/heldout_test" "$WORK/heldout_test" --out "$RES/identify_exact.json"
fit exact_rotated90 "$WORK/heldout_test" rotated90 "parts_pool[224:256] (exact renders)"
fit exact_other "$WORK/heldout_test" other "parts_pool[224:256] (exact renders)"
fit fast_true "$WORK/rheldout_fast" true "parts_pool[224:256]/recon=fast"
[ -f "$RES/identify_fast.json" ] || $PY -m experiments.known_light.identify "$WORK/heldout_test" "$WORK/rheldout_fast" --out "$RES/identify_fast.json"
# A first light-aware Stage II (ablation=light_full: the read-out as a condition, a fifth of the
# training scenes told a wrong light) with the shipped recipe on 64 training-pool scenes' exact
# renders (Table 2's training keys), in 50-minute chunks (rerun to resume), measured on the
# held-out exact renders under the estimated light (Table 2's measure).
# measure DATA LABEL CHECKPOINT NAME [points_measure overrides]: Table 2's measure of a Stage II
# checkpoint on DATA's held-out scenes, its scores committed as results/NAME (an override is another
# measure hash); held_out_measure: on the held-out scenes behind their recon=fast assets
measure() {
  local data=$1 label=$2 ckpt=$3 m=$4; shift 4
  [ -f "$RES/$m/scores.json" ] || { .venv/bin/gspi-points-eval checkpoint="$ckpt" \
    data="$data" out="$WORK/runs/$m" baseline="$BASE" points_measure=table2 "$@" && \
    $PY -c "from pathlib import Path; from eval.portable import write_portable_scores as w; w(Path('$WORK/runs/$m/scores.json'), Path('$RES/$m/scores.json'), data_label='$label', roots={'<work>': Path('$WORK')})"; }
}
held_out_measure() { measure "$WORK/rheldout_fast" "parts_pool[224:256]/recon=fast" "$@"; }
ckpt_step() { $PY -c "import torch; print(torch.load('$1', map_location='cpu', weights_only=True, mmap=True)['step'])"; }
RUN="$WORK/runs/train_light_full_s0"
KEPT=experiments/known_light/resume/light_full_s0/checkpoint.pt   # the training's state at the last session's stop
if [ ! -f "$RUN/checkpoint.pt" ] && [ -f "$KEPT" ]; then mkdir -p "$RUN" && cp "$KEPT" "$RUN/checkpoint.pt"; fi
.venv/bin/gspi-train data="$WORK/train_view" out="$RUN" stage2=cpu_pool224_pixel_5k ablation=light_full seed=0 \
  stage2.train.stop_after_minutes=50 stage2.train.run_log=null
STEP=$(ckpt_step "$RUN/checkpoint.pt")
# one measure per checkpoint step: a learning curve
measure "$WORK/heldout_test" "parts_pool[224:256] (exact renders)" "$RUN/checkpoint.pt" "light_full_s0_step${STEP}_exact"
# the state travels in git while the training is under way, and leaves when it ends
if [ "$STEP" -lt 5000 ]; then cp "$RUN/checkpoint.pt" "$KEPT"; else rm -f "$KEPT"; fi
# What the learned rows are given: the condition's own read-out scored as the prediction.
[ -f "$RES/condition_readout/scores.json" ] || $PY -m experiments.known_light.condition "$RUN/checkpoint.pt" \
  "$WORK/heldout_test" "$WORK/runs/condition_readout" --baseline "$BASE" --results "$RES/condition_readout" \
  --label "parts_pool[224:256] (exact renders)"
# ablation=light_residual: the same, the x0 head correcting the read-out (starts as the read-out).
RUN="$WORK/runs/train_light_residual_s0"
KEPT=experiments/known_light/resume/light_residual_s0/checkpoint.pt
if [ ! -f "$RUN/checkpoint.pt" ] && [ -f "$KEPT" ]; then mkdir -p "$RUN" && cp "$KEPT" "$RUN/checkpoint.pt"; fi
.venv/bin/gspi-train data="$WORK/train_view" out="$RUN" stage2=cpu_pool224_pixel_5k ablation=light_residual seed=0 \
  stage2.train.stop_after_minutes=50 stage2.train.run_log=null
STEP=$(ckpt_step "$RUN/checkpoint.pt")
measure "$WORK/heldout_test" "parts_pool[224:256] (exact renders)" "$RUN/checkpoint.pt" "light_residual_s0_step${STEP}_exact"
if [ "$STEP" -lt 5000 ]; then mkdir -p "$(dirname "$KEPT")" && cp "$RUN/checkpoint.pt" "$KEPT"; else rm -f "$KEPT"; fi
# Behind the held-out scenes' recon=fast assets (Table 2's measure on the reconstructed pool): the
# exact-render light_residual and the read-out it is given, read on the GT cloud in the assets' renders
# (the condition's default geometry) and as a run reads it (--asset: Stage I's cloud, the photos).
for G in "" _asset; do
  [ -f "$RES/condition_readout_fast$G/scores.json" ] || $PY -m experiments.known_light.condition "$RUN/checkpoint.pt" \
    "$WORK/rheldout_fast" "$WORK/runs/condition_readout_fast$G" --baseline "$BASE" \
    --results "$RES/condition_readout_fast$G" --label "parts_pool[224:256]/recon=fast" ${G:+--asset}
done
held_out_measure "$RUN/checkpoint.pt" "light_residual_s0_step${STEP}_fast"
# Under the conditions users' assets have (issue 66, item 5): light_residual trained on the 64
# training scenes' recon=fast assets, its read-out read as a run reads it (light_geometry=asset,
# normals searched), in 40-minute chunks (rerun to resume), measured behind the held-out assets.
# asset_prior NAME CONDITION OVERRIDES...: one chunk of the asset-trained light_residual NAME_s$SEED
# (40 minutes; kept state in resume/NAME_s$SEED/ while under way), the condition it is given scored
# once (results/CONDITION), the prior at the step reached (results/NAME_s$SEED_step<N>_fast).
# train_chunk NAME DATA OVERRIDES...: one 40-minute chunk of light_residual NAME_s$SEED trained on DATA,
# resumed from its kept state in resume/NAME_s$SEED/ (kept there while under way, removed at 5000);
# STEP: the step reached (the recipe's stop_after_cpu_minutes=60 also ends a call at ~4200: rerun)
train_chunk() {
  local name=$1 data=$2; shift 2
  local run="$WORK/runs/train_${name}_s$SEED" kept=experiments/known_light/resume/${name}_s$SEED/checkpoint.pt
  if [ ! -f "$run/checkpoint.pt" ] && [ -f "$kept" ]; then mkdir -p "$run" && cp "$kept" "$run/checkpoint.pt"; fi
  .venv/bin/gspi-train data="$data" out="$run" stage2=cpu_pool224_pixel_5k ablation=light_residual seed=$SEED \
    stage2.train.stop_after_minutes=40 stage2.train.run_log=null "$@"
  STEP=$(ckpt_step "$run/checkpoint.pt")
  if [ "$STEP" -lt 5000 ]; then mkdir -p "$(dirname "$kept")" && cp "$run/checkpoint.pt" "$kept"; else rm -rf "$(dirname "$kept")"; fi
}
asset_prior() {
  local name=$1 condition=$2; shift 2
  train_chunk "$name" "$WORK/rtrain_fast" "$@"
  local run="$WORK/runs/train_${name}_s$SEED/checkpoint.pt"
  [ -f "$RES/$condition/scores.json" ] || $PY -m experiments.known_light.condition \
    "$run" "$WORK/rheldout_fast" "$WORK/runs/$condition" --baseline "$BASE" \
    --results "$RES/$condition" --label "parts_pool[224:256]/recon=fast"   # what it is given
  held_out_measure "$run" "${name}_s${SEED}_step${STEP}_fast"
}
AS_A_RUN=(stage2.data.light_geometry=asset 'stage2.data.light_normal_search_deg=[4,8]' stage2.data.light_normal_profile=3)
METAL_GATE=(stage2.data.light_metal_min_evidence=1.1 stage2.diffusion.readout_metal_gate=true)   # finding 28's recipe
for SEED in 0 1; do   # two seeds (the issue's); each resumes from its kept state
  asset_prior light_residual_asset condition_readout_fast_asset_profile "${AS_A_RUN[@]}"
done
# The same prior given the read-out with the scene-level metal test (finding 20; finding 26):
# stage2.data.light_metal_min_evidence=1.1 as light_fit's method.metal_min_evidence; two seeds.
for SEED in 0 1; do
  asset_prior light_residual_gated_asset condition_readout_fast_asset_gated "${AS_A_RUN[@]}" stage2.data.light_metal_min_evidence=1.1
done
# ... its seed 0 with 4 DDIM samples averaged per point: how much of its gap to its condition is sampling noise
held_out_measure "$WORK/runs/train_light_residual_gated_asset_s0/checkpoint.pt" \
  light_residual_gated_asset_s0_step5000_fast_4samples points_measure.num_samples=4
# ... read as its posterior mean (one DDIM step), and with the metal gate switched on after
# training (gate_checkpoint.py), both seeds; the shipped Full read the same way (finding 28)
for SEED in 0 1; do
  run="$WORK/runs/train_light_residual_gated_asset_s$SEED/checkpoint.pt" gated="$WORK/runs/gated_asset_s${SEED}_step5000_metalgate.pt"
  [ -f "$gated" ] || $PY -m experiments.known_light.gate_checkpoint "$run" "$gated"
  held_out_measure "$run" "light_residual_gated_asset_s${SEED}_step5000_fast_1step" points_measure.num_steps=1
  held_out_measure "$gated" "light_residual_gated_asset_s${SEED}_step5000_fast_metalgate"
  held_out_measure "$gated" "light_residual_gated_asset_s${SEED}_step5000_fast_metalgate_1step" points_measure.num_steps=1
done
held_out_measure checkpoints/stage2_pool224_pixel_5k.pt full_s0_fast_1step points_measure.num_steps=1
# The next recipe (finding 28): the same prior trained with the metal gate (a prior that cannot undo the
# scene-level test), two seeds in 40-minute chunks; read as its posterior mean at the end.
for SEED in 0 1; do
  asset_prior light_residual_metalgate_asset condition_readout_fast_asset_gated "${AS_A_RUN[@]}" "${METAL_GATE[@]}"
  run="$WORK/runs/train_light_residual_metalgate_asset_s$SEED/checkpoint.pt"
  [ ! -f "$run" ] || [ "$(ckpt_step "$run")" -lt 5000 ] || {
    held_out_measure "$run" "light_residual_metalgate_asset_s${SEED}_step5000_fast_1step" points_measure.num_steps=1
    held_out_measure "$run" "light_residual_metalgate_asset_s${SEED}_step5000_fast_1step_4samples" \
      points_measure.num_steps=1 points_measure.num_samples=4   # the mean over 4 noise draws
    for T in turned90 other; do  # issue 66's guard rail: told a deliberately wrong light
      held_out_measure "$run" "light_residual_metalgate_asset_s${SEED}_step5000_fast_1step_told_$T" \
        points_measure.num_steps=1 points_measure.told_light=$T
    done; }
done
# ... and end to end on the controlled pairs (the 6-pair set, `colours=1`): its seed 0 through gspi-run
# behind recon=fast, read as its posterior mean (finding 31; shipping_rule.py reads the record)
pairs_run() {  # RECORD CHECKPOINT [gspi-run overrides]: results/controlled_pairs/RECORD.json
  local name=$1 ckpt=$2; shift 2
  [ -f "$RES/controlled_pairs/$name.json" ] && return
  [ -f "$WORK/pairs/pairs6/splits.json" ] || .venv/bin/gspi-data data=controlled_pairs out="$WORK/pairs/pairs6" seed=0 \
    data.controlled_pairs.colours=1
  .venv/bin/gspi-run data_dir="$WORK/pairs/pairs6" out="$WORK/pairs/$name" stage2.checkpoint="$ckpt" \
    stage2.inference.num_steps=1 logger=none progress=false figures=false "$@"
  mkdir -p "$RES/controlled_pairs" && $PY benchmarks/bench_controlled_pairs.py "$WORK/pairs/$name" \
    --data "$WORK/pairs/pairs6" --json "$RES/controlled_pairs/$name.json"
  sed -i "s#$WORK#<work>#g" "$RES/controlled_pairs/$name.json"
}
pairs_run light_residual_metalgate_asset_s0_1step "$WORK/runs/train_light_residual_metalgate_asset_s0/checkpoint.pt" recon=fast
# The same recipe with both pools behind the early-normal-consistency Stage 0 (finding 12's assets;
# finding 32): ~30 min of Stage 0 on 2 cores, two seeds of 5 000 steps in 40-minute chunks (kept
# state in resume/ while under way), measured behind the held-out pool's assets of the same Stage 0.
NC=(recon.loss.normal_from_iter=150 recon.loss.lambda_normal=0.2)
for POOL in heldout_test:rheldout_nc train_view:rtrain_nc; do
  $PY -m gspi.recon.reconstructed_pool "$WORK/${POOL%%:*}" "$WORK/${POOL##*:}" --recon fast --workers 1 "${NC[@]}"
  $PY -m gspi.stage1.pool_clouds "$WORK/${POOL##*:}"
done
nc_measure() { measure "$WORK/rheldout_nc" "parts_pool[224:256]/recon=fast+normal_from_iter=150,lambda_normal=0.2" "$@"; }
nc_measure checkpoints/stage2_pool224_pixel_5k.pt full_s0_fast_nc   # the default behind the same assets
for SEED in 0 1; do
  train_chunk light_residual_metalgate_nc "$WORK/rtrain_nc" "${AS_A_RUN[@]}" "${METAL_GATE[@]}"
  [ "$STEP" -ge 5000 ] || continue
  run="$WORK/runs/train_light_residual_metalgate_nc_s$SEED/checkpoint.pt"
  nc_measure "$run" "light_residual_metalgate_nc_s${SEED}_step5000_fast_nc_1step" points_measure.num_steps=1
  nc_measure "$run" "light_residual_metalgate_nc_s${SEED}_step5000_fast_nc_1step_4samples" \
    points_measure.num_steps=1 points_measure.num_samples=4
done
# ... its seed 0 on the controlled pairs behind the same Stage 0
run="$WORK/runs/train_light_residual_metalgate_nc_s0/checkpoint.pt"
[ "$(ckpt_step "$run")" -lt 5000 ] || pairs_run light_residual_metalgate_nc_s0_1step "$run" recon=fast "${NC[@]}"
# The same recipe trained on 64 training scenes drawn with the held-out pool's keys (no
# `matte_finish`; the parts pool [0:64], the scenes Table 2's constants come from, never its test
# scenes [224:256]): is the prior's matte lean (finding 31) its training scenes'? ~10 min of data and
# ~30 min of Stage 0 on one thread, then two seeds in 40-minute chunks, each measure at the step reached.
training_data _hk "$KEYS"
[ -f "$RES/pool_roughness.json" ] || $PY -m experiments.known_light.pool_roughness \
  "training, Table 2's keys (matte_finish=0.5) [0:64]=$WORK/train_view" "training, the held-out keys [0:64]=$WORK/train_view_hk" \
  "held-out [224:256]=$WORK/heldout_test" --out "$RES/pool_roughness.json"   # each pool's dielectric roughness
for SEED in 0 1; do
  train_chunk light_residual_metalgate_hk "$WORK/rtrain_hk_fast" "${AS_A_RUN[@]}" "${METAL_GATE[@]}"
  held_out_measure "$WORK/runs/train_light_residual_metalgate_hk_s$SEED/checkpoint.pt" \
    "light_residual_metalgate_hk_s${SEED}_step${STEP}_fast_1step" points_measure.num_steps=1
done
run="$WORK/runs/train_light_residual_metalgate_hk_s0/checkpoint.pt"
[ "$(ckpt_step "$run")" -lt 5000 ] || pairs_run light_residual_metalgate_hk_s0_1step "$run" recon=fast
# The same priors with their x0 head's roughness correction scaled after training (finding 35;
# shrink_checkpoint.py): x0 = read-out + S * correction, S 0 the read-out, 1 the prior; each S
# measured held out and on the controlled pairs, no retraining.
shrunk_prior() {  # SEED S [M]: roughness correction x S (and metallic x M), held out and (seed 0) on the pairs
  local src="$WORK/runs/train_light_residual_metalgate_hk_s$1/checkpoint.pt" read="rough_x$2${3:+_metal_x$3}"
  local ck="$WORK/runs/hk_s$1_step5000_$read.pt"
  [ -f "$src" ] && [ "$(ckpt_step "$src")" -ge 5000 ] || return 0
  [ -f "$ck" ] || $PY -m experiments.known_light.shrink_checkpoint "$src" "$ck" --scale "$2" ${3:+--metallic "$3"}
  held_out_measure "$ck" "light_residual_metalgate_hk_s$1_step5000_fast_1step_$read" points_measure.num_steps=1
  if [ "$1" = 0 ]; then pairs_run "light_residual_metalgate_hk_s0_1step_$read" "$ck" recon=fast; fi
}
for S in 0.25 0.5 0.75; do shrunk_prior 0 $S; done
shrunk_prior 1 0.5
for SEED in 0 1; do shrunk_prior $SEED 0.5 0; done   # ... and without its metallic correction (the read-out's metallic)
for T in turned90 other; do  # its guard rail (seed 0)
  held_out_measure "$WORK/runs/hk_s0_step5000_rough_x0.5.pt" "light_residual_metalgate_hk_s0_step5000_fast_1step_rough_x0.5_told_$T" \
    points_measure.num_steps=1 points_measure.told_light=$T
done
# A scene-level metal test for the read-out (finding 18; metal_gate.py): the threshold on every
# other training scene, scored on the held-out ones (each file resumes where it stopped).
$PY -m experiments.known_light.metal_gate "$WORK/rtrain_fast" "$WORK/rtrain_fast" "$RES/metal_gate_train.json" --baseline "$BASE" --every 2
$PY -m experiments.known_light.metal_gate "$WORK/heldout_test" "$WORK/rheldout_fast" "$RES/metal_gate_heldout.json" --baseline "$BASE"
$PY -m experiments.known_light.metal_gate --table "$RES/metal_gate_train.json" "$RES/metal_gate_heldout.json"
# The read-out's cost against its quality (finding 22): 20 000 points vs 1/2/3 per Gaussian.
$PY -m experiments.known_light.light_budget "$WORK/heldout_test" "$WORK/rheldout_fast" "$RES/light_budget.json" --baseline "$BASE"
$PY -m experiments.known_light.light_budget --table "$RES/light_budget.json"
# The read-out's pooling behind Stage 0 (finding 25): (k, T) chosen on every other training scene, scored held out.
$PY -m experiments.known_light.pooling "$WORK/rtrain_fast" "$WORK/rtrain_fast" "$RES/pooling_train.json" --baseline "$BASE" --every 2
$PY -m experiments.known_light.pooling "$WORK/heldout_test" "$WORK/rheldout_fast" "$RES/pooling_heldout.json" --baseline "$BASE"
$PY -m experiments.known_light.pooling --table "$RES/pooling_train.json" "$RES/pooling_heldout.json"
# Not an inverse crime (issue 66, item 6; finding 29; end_to_end.py): light_fit end to end beside
# GS-PI's default and no decomposition on the demo's small test scenes path-traced and captured
# under real HDRIs in no candidate set (assets reconstructed from those photos), and on the 19 real
# glTF objects; each run's scores copied to results/end_to_end/<variant>/.
small_variant() {  # NAME DATA_OVERRIDES...
  local dir="$WORK/$1" name=$1; shift
  [ -f "$dir/data_done" ] || { rm -rf "$dir/data" && .venv/bin/gspi-data preset=small out="$dir/data" seed=0 \
    'data.only_splits=[test]' "$@" && touch "$dir/data_done"; }
  [ -d "$RES/end_to_end/$name" ] || { .venv/bin/gspi-run -m data="$dir/data" out="$dir/runs" +experiment=demo \
    assets=null logger=none method=gspi,no_decomposition,light_fit && \
    $PY -m experiments.known_light.end_to_end collect "$name" "$dir/runs"; }
}
small_variant pathtraced data.renderer=pathtraced
small_variant polyhaven_capture data.capture_envs=polyhaven
[ -d "$RES/end_to_end/polyhaven_capture_refined" ] || { .venv/bin/gspi-run -m data="$WORK/polyhaven_capture/data" \
  out="$WORK/polyhaven_capture/runs_refined" +experiment=demo assets=null logger=none method=light_fit \
  method.light_refine=true && $PY -m experiments.known_light.end_to_end collect polyhaven_capture_refined \
  "$WORK/polyhaven_capture/runs_refined"; }
[ -d "$RES/end_to_end/polyhaven_capture_in_set" ] || { .venv/bin/gspi-run -m data="$WORK/polyhaven_capture/data" \
  out="$WORK/polyhaven_capture/runs_in_set" +experiment=demo assets=null logger=none method=light_fit \
  method.candidates=polyhaven && $PY -m experiments.known_light.end_to_end collect polyhaven_capture_in_set \
  "$WORK/polyhaven_capture/runs_in_set"; }
# ... and with the candidates' maps at the photos' own 128 rows (finding 30: what the map's resolution costs)
[ -d "$RES/end_to_end/polyhaven_capture_in_set_128" ] || { .venv/bin/gspi-run -m data="$WORK/polyhaven_capture/data" \
  out="$WORK/polyhaven_capture/runs_in_set_128" +experiment=demo assets=null logger=none method=light_fit \
  method.candidates=polyhaven method.env_height=128 && $PY -m experiments.known_light.end_to_end collect \
  polyhaven_capture_in_set_128 "$WORK/polyhaven_capture/runs_in_set_128"; }
# ... and the study's learned candidate on the same inputs (end_to_end.py's PRIORS; finding 33): GS-PI with
# finding 30's metal-gate prior (seed 0, step 5000, one DDIM step), its job folder named as the others'
prior_run() {  # NAME DATA EXPERIMENT CHECKPOINT [overrides]: results/end_to_end/NAME/method=gspi, read as its posterior mean
  local name=$1 data=$2 experiment=$3 ckpt=$4; shift 4
  [ -d "$RES/end_to_end/$name" ] || { .venv/bin/gspi-run -m data="$data" out="$WORK/$name/runs" +experiment="$experiment" \
    logger=none method=gspi stage2.checkpoint="$ckpt" stage2.inference.num_steps=1 "hydra.sweep.subdir='method=gspi'" "$@" && \
    $PY -m experiments.known_light.end_to_end collect "$name" "$WORK/$name/runs"; }
}
prior_variant() {  # NAME DATA [EXPERIMENT]: prior_run with finding 30's prior, assets reconstructed (EXPERIMENT: demo)
  prior_run "$1" "$2" "${3:-demo}" "$WORK/runs/train_light_residual_metalgate_asset_s0/checkpoint.pt" assets=null
}
prior_variant polyhaven_capture_prior "$WORK/polyhaven_capture/data"
prior_variant pathtraced_prior "$WORK/pathtraced/data"
[ -f "$WORK/real/data_done" ] || { rm -rf "$WORK/real/data" && .venv/bin/gspi-data \
  import.glb=../shared/data/real-objects out="$WORK/real/data" preset=small && touch "$WORK/real/data_done"; }
[ -d "$RES/end_to_end/real_objects" ] || { .venv/bin/gspi-run -m data="$WORK/real/data" out="$WORK/real/runs" \
  +experiment=real_objects logger=none method=light_fit,no_decomposition && \
  $PY -m experiments.known_light.end_to_end collect real_objects "$WORK/real/runs"; }
prior_variant real_objects_prior "$WORK/real/data" real_objects
# Finding 35's candidate (the held-out-keys prior, its roughness correction halved) through issue 42's
# end-to-end checks: the 19 real objects (seed 0) and the demo's 4 scenes with its embedded assets (both seeds)
HK="$WORK/runs/train_light_residual_metalgate_hk_s0/checkpoint.pt"   # finding 34's prior as trained
prior_run real_objects_hk_x05 "$WORK/real/data" real_objects "$WORK/runs/hk_s0_step5000_rough_x0.5.pt" hydra.launcher.n_jobs=1
prior_run real_objects_hk_x1 "$WORK/real/data" real_objects "$HK" hydra.launcher.n_jobs=1   # as trained
[ -f "$WORK/small_demo/data_done" ] || { rm -rf "$WORK/small_demo/data" && .venv/bin/gspi-data preset=small \
  out="$WORK/small_demo/data" seed=0 'data.only_splits=[test]' && touch "$WORK/small_demo/data_done"; }
for SEED in 0 1; do
  prior_run splitsum_hk_x05_s$SEED "$WORK/small_demo/data" demo "$WORK/runs/hk_s${SEED}_step5000_rough_x0.5.pt" hydra.launcher.n_jobs=1
done
M0="$WORK/runs/hk_s0_step5000_rough_x0.5_metal_x0.pt"   # ... without its metallic correction (seed 0)
prior_run splitsum_hk_x05_m0_s0 "$WORK/small_demo/data" demo "$M0" hydra.launcher.n_jobs=1
prior_run real_objects_hk_x05_m0 "$WORK/real/data" real_objects "$M0" hydra.launcher.n_jobs=1
$PY -m experiments.known_light.tables

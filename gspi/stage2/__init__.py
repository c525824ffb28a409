"""Stage II: conditional point-cloud diffusion of per-point PBR features (paper Sec. 3.3).

Modules: ``inputs`` (Stage2Inputs), ``normalize`` (unit sphere, [-1, 1] features),
``blocks`` + ``model`` (RCW denoiser), ``schedule`` (cosine, q_sample, Min-SNR),
``loss`` (training objective), ``sampler`` (DDIM), ``encoders`` + ``feature_cache`` (global
prior), ``data`` (training items), ``train`` (loop, EMA, resume), ``sampler`` (DDIM, ``predict_point_pbr``),
``checkpoint`` (files, ``load_stage2_checkpoint``), ``evaluate_points`` (Table 2's measure),
``train_log`` (metrics.jsonl, loss curve). See docs/STAGE2.md.
"""

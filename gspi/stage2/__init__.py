"""Stage II: conditional point-cloud diffusion of per-point PBR features (paper Sec. 3.3).

Modules: ``inputs`` (Stage2Inputs), ``normalize`` (unit sphere, [-1, 1] features),
``blocks`` + ``model`` (RCW denoiser), ``schedule`` (cosine, q_sample, Min-SNR),
``loss`` (training objective), ``sampler`` (DDIM).
"""

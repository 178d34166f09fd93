"""Lifting phase (Dynamic Panoramic Lifting): panoramic video → per-timestamp Gaussians.

``pipeline``: the stages in order, from the animation frames to the optimised sets.
``depth``: monocular depth backends (layout prior, depth file, DPT / Depth Anything).
``align``: spatial-temporal alignment of per-view depth into one spherical depth per frame.
``initial``: initial Gaussians from the aligned depth, static/dynamic split.
``trainer``: what a trainer is (``Trainer``) and is given (``TrainViews``, ``Knobs``).
``torch_trainer``, ``resident``: the trainers, the torch reference and the one on the GPU
(the default); their losses are ``losses``', their densification ``densify``'s.
``trainers``: which trainers exist (what the command line and ``pipeline`` read).
``features``: the DINOv2 feature backend for L_sem.
``checkpoints``: each stage's saved state, so a killed run resumes.
``export``: the files a run writes (scene.ply4d, preview, contact sheet, metrics).
``pano4d.train`` runs the animating phase, then this one.
"""

"""Lifting phase (Dynamic Panoramic Lifting): panoramic video → per-timestamp Gaussians.

``depth``: monocular depth backends (layout prior, depth file, DPT / Depth Anything).
``align``: spatial-temporal alignment of per-view depth into one spherical depth per frame.
``initial``: initial Gaussians from the aligned depth, static/dynamic split.
``optimize``: per-timestamp optimisation (L_rgb, L_temporal, L_geo, L_sem), densify/prune.
``features``: the DINOv2 feature backend for L_sem.
The pipeline that runs them in order, with checkpoints, is ``pano4d.train``.
"""

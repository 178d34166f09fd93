"""Animating phase: a static panorama becomes a looping panoramic video (docs/design.md).

``pipeline.run_animate(cfg)`` runs the phase (``pano4d animate``) on the masks, soft blend and
motion of ``pano4d.regions``; ``flow`` is the embedded animator
that needs no weights; the Panoramic Denoiser (``denoiser``, ``svd``, ``noise``, ``decode``)
animates with a diffusers image-to-video model. Submodules are imported on use, so the
default animator never loads diffusers.
"""

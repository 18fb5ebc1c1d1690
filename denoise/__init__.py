"""Spatio-temporal denoising of 1-spp frames with G-buffers (Dr.Jit arrays).

The course's real-time denoising assignment: a joint bilateral filter on the
G-buffers, its À-Trous wavelet speed-up, back projection to the previous frame
and temporal accumulation with clamping. :mod:`denoise.filters` holds the
kernels, :mod:`export.frames` the frame folders, :mod:`export` renders
sequences, ``python -m denoise`` runs the denoiser on a folder.
"""
